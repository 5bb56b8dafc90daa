"""The device protocols' codecs and set-up, against the stand-ins on python-can's virtual bus.

Expected values come from the standards' definitions (ISO 11783-7 scaling, CiA 301
mapping entries, CiA 401 objects), written here, not from the driver's output.
"""
from __future__ import annotations

import itertools
import math
import struct
import time

import can
import cantools
import numpy as np
import pytest
from suite_waits import wait_until

from valve_driver_pkg.devices.canopen_mapping import default_eds_path, load_canopen_mapping
from valve_driver_pkg.devices.canopen_protocol import CanopenProtocol
from valve_driver_pkg.devices.core import DeviceDriverCore
from valve_driver_pkg.devices.derived import DerivedOpening
from valve_driver_pkg.devices.dbc_protocol import (DbcProtocol, example_dbc_path,
                                                   example_mapping_path, load_dbc_mapping)
from valve_driver_pkg.devices.j1939_codec import (decode_dm1, decode_estimated_flow,
                                                  encode_valve_command)
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.errors import MappingError
from valve_driver_pkg.standins.canopen_device import CanopenDevice
from valve_driver_pkg.standins.plant import ValvePlant
from valve_model_pkg.maps import load_map
from valve_model_pkg.model import load_parameters

_channels = itertools.count()


def test_valve_command_carries_iso_11783_7_scaling() -> None:
    can_id, data = encode_valve_command(2, 0x80, 0.5)
    assert can_id == (3 << 26) | (0xFE32 << 8) | 0x80        # PGN 65074, priority 3
    assert data[0] == 125                                   # 50 % / 0.4 %/bit
    assert data[1] & 0x03 == 0b01                           # extended resolution valid
    assert data[2] & 0x0F == 1 and data[2] >> 6 == 0        # extend, fail-safe block
    assert int.from_bytes(data[3:5], 'little') == 32000     # 50 % / 0.0015625 %/bit
    _, stop = encode_valve_command(2, 0x80, 0.0)
    assert stop[0] == 0 and stop[2] & 0x0F == 0 and stop[3:5] == b'\0\0'   # block


def test_estimated_flow_and_dm1_decode() -> None:
    flow = decode_estimated_flow(bytes([175, 125, 0x1C, 0xC0, 0x1F, 255, 255, 255]))
    assert flow.extend_pct == 50.0 and flow.retract_pct == 0.0 and flow.state == 1
    assert decode_estimated_flow(bytes([0xFF, 125, 0, 0])).extend_pct != \
        decode_estimated_flow(bytes([0xFF, 125, 0, 0])).extend_pct    # NaN: not available
    # SPN 1907 = 0x773, FMI 5, 3 occurrences; SPN 524287 (19 bits all set), FMI 31
    dm1 = decode_dm1(bytes([0x04, 0xFF, 0x73, 0x07, 0x05, 0x03, 0xFF, 0xFF, 0xFF, 0x01]))
    assert [(d.spn, d.fmi, d.occurrences) for d in dm1.dtcs] == [(1907, 5, 3),
                                                                 (524287, 31, 1)]
    assert dm1.amber == 1 and dm1.red_stop == 0
    assert decode_dm1(bytes([0, 0xFF, 0, 0, 0, 0, 0xFF, 0xFF])).dtcs == ()


@pytest.fixture
def canopen_rig():
    channel = f'devices_{next(_channels)}'
    device_bus = can.Bus(interface='virtual', channel=channel)
    device = CanopenDevice(device_bus, 5, ValvePlant())
    device.start()
    config = DriverConfig(protocol='canopen', interface='virtual', channel=channel,
                          command_timeout_s=0.0)
    protocol = CanopenProtocol(5, 127, str(default_eds_path()), load_canopen_mapping(), 100,
                               0.3, 0.01)
    states = []
    core = DeviceDriverCore(config, protocol, on_state=states.append,
                            bus_factory=lambda i, c, b, connect_timeout=0.0: can.Bus(
                                interface='virtual', channel=c))
    yield core, device, states
    core.close()
    device.stop()
    device_bus.shutdown()


def _od(device: CanopenDevice, index: int, sub: int, fmt: str) -> int:
    return struct.unpack(fmt, device.node.get_data(index, sub))[0]


def test_canopen_set_up_writes_consumer_error_behaviour_and_cia301_mapping(
        canopen_rig) -> None:
    core, device, states = canopen_rig
    core.open()
    assert _od(device, 0x1016, 1, '<I') == (127 << 16) | 300      # 3 x 100 ms
    assert _od(device, 0x1017, 0, '<H') == 100
    assert _od(device, 0x6443, 1, '<B') == 1
    assert _od(device, 0x6444, 1, '<i') == 0
    assert _od(device, 0x1600, 0, '<B') == 1
    assert _od(device, 0x1600, 1, '<I') == 0x6411_01_10          # index, sub, 16 bits
    assert _od(device, 0x1A00, 1, '<I') == 0x6401_01_10
    assert _od(device, 0x1400, 1, '<I') == 0x205                   # valid, 0x200 + id
    core.activate()
    core.set_command(0.42)
    wait_until(lambda: device.plant.duty == pytest.approx(0.42), what='per mille at device')
    assert _od(device, 0x6411, 1, '<h') == 420
    wait_until(lambda: len(states) > 3, what='TPDO1 -> state')
    # a device that reboots with the defaults of its dictionary is set up again
    device.node.data_store.clear()
    device.network.notify(0x000, bytes([0x81, 5]), time.time())   # NMT reset node
    wait_until(lambda: _od(device, 0x1016, 1, '<I') == (127 << 16) | 300
               and device.plant.duty == pytest.approx(0.42), what='re-set-up after boot-up')
    assert core.counters['setups'] >= 2


def test_canopen_mapping_naming_a_missing_object_is_refused(tmp_path) -> None:
    path = tmp_path / 'm.yaml'
    path.write_text('duty: {object: 0x6411, subindex: 7, type: INTEGER16, scale: 0.001}\n')
    with pytest.raises(MappingError, match=r'0x6411 sub 7 is not in the EDS'):
        CanopenProtocol(5, 127, str(default_eds_path()), load_canopen_mapping(path), 100,
                        0.3, 0.01)


def test_dbc_duty_in_percent_motorola_and_the_counter() -> None:
    protocol = DbcProtocol.from_files(str(example_dbc_path()), str(example_mapping_path()),
                                      0.01)
    assert protocol.command_period_s == pytest.approx(0.02)     # GenMsgCycleTime 20 ms
    assert protocol.liveness_period_s == pytest.approx(0.1)
    db = cantools.database.load_file(str(example_dbc_path()))
    first, second = (protocol.command_frames(0.6, True)[0] for _ in range(2))
    decoded = db.decode_message(first.arbitration_id, first.data)
    assert decoded['DutyPct'] == pytest.approx(60.0) and decoded['Enable'] == 1
    assert first.data[0:2] == (6000).to_bytes(2, 'big')        # Motorola: MSB first
    assert (db.decode_message(second.arbitration_id, second.data)['Alive']
            - decoded['Alive']) % 16 == 1
    status = db.get_message_by_name('BoardStatus')
    frame = can.Message(arbitration_id=status.frame_id, is_extended_id=True,
                        data=status.encode({'Page': 0, 'CoilCurrent': 480, 'DutyActual': 60}))
    assert protocol.on_frame(frame).reading.coil_current_a == pytest.approx(0.48)


@pytest.mark.parametrize('line, name', [('duty: BoardCmd.DutyPct', "message 'BoardCmd'"),
                                        ('duty: BoardCommand.Duty', "signal 'Duty'"),
                                        ('duty: BoardStatus.SupplyVoltage', "unit 'V'")])
def test_dbc_mapping_refusals_name_what_is_wrong(tmp_path, line: str, name: str) -> None:
    path = tmp_path / 'm.yaml'
    path.write_text(line + '\n')
    with pytest.raises(MappingError, match=name):
        load_dbc_mapping(str(example_dbc_path()), str(path))


def test_derived_opening_is_the_duty_maps_steady_state() -> None:
    duty_map = load_map()
    derived = DerivedOpening.load('', load_parameters(), 'the default parameters')
    stroke_m = load_parameters().stroke_m
    curve = duty_map.curve(50.0, 400_000.0)
    for duty in (0.3, 0.5, 0.7):
        i = int(np.flatnonzero(np.isclose(duty_map.duty, duty))[0])
        assert derived.position_avg_m(duty, 50.0, 400_000.0) == pytest.approx(
            curve[i] * stroke_m, rel=1e-9)
    assert derived.position_avg_m(0.0, 50.0, 400_000.0) == 0.0
    assert math.isnan(derived.position_avg_m(0.5, 60.0, 400_000.0))   # no 60 Hz curve
    assert not derived.covers(60.0) and derived.covers(50.0)


def test_a_duty_map_of_another_valve_is_refused_naming_the_parameter() -> None:
    other = load_parameters().replace(stroke_m=0.3e-3)
    with pytest.raises(MappingError, match='stroke_m'):
        DerivedOpening.load('', other, 'params.yaml')
