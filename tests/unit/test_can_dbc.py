"""The DBC as a CAN engineer imports it: attributes, value tables, an id plan beside CANopen."""
from __future__ import annotations

import random

import cantools
import pytest

from valve_driver_pkg.driver import CanDriverCore, DriverConfig
from valve_driver_pkg.protocol import (COMMAND, CONTROL, DRIVE, PERIOD, PRESSURE, STATUS,
                                       TELEMETRY, TELEMETRY_MEAN, DriveMode,
                                       EmulatorFault, ValveCodec, crc8, default_dbc_path,
                                       fault_injection_dbc_path)
from valve_driver_pkg.protocol.codec import MAX_NODE_ID

# (cycle time [ms], send type) of every message, as the protocol documents them.
TIMING = {COMMAND: (10, 'CyclicAndSpontaneous'), TELEMETRY: (1, 'Cyclic'),
          PERIOD: (100, 'CyclicAndSpontaneous'), PRESSURE: (100, 'CyclicAndSpontaneous'),
          STATUS: (100, 'Cyclic')}
# The messages with a 29-bit id (the 11-bit block beside CANopen is full).
TIMING_EXTENDED = {TELEMETRY_MEAN: (1, 'Cyclic'), DRIVE: (100, 'CyclicAndSpontaneous')}


def _canopen_ids() -> set[int]:
    """Every 11-bit id CANopen's predefined connection set or restricted list uses (CiA 301)."""
    ids = {0x000, 0x080, 0x100}                                   # NMT, SYNC, TIME
    for node in range(1, 128):
        ids |= {base + node for base in (0x080, 0x180, 0x200, 0x280, 0x300, 0x380, 0x400,
                                         0x480, 0x500, 0x580, 0x600, 0x700)}
    ids |= set(range(0x001, 0x080)) | set(range(0x101, 0x181))   # restricted
    ids |= set(range(0x6E0, 0x700)) | set(range(0x780, 0x800))   # restricted, LSS
    return ids


def test_cycle_times_send_types_and_bus_type_are_attributes() -> None:
    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    assert db.dbc.attributes['BusType'].value == 'CAN'
    assert {m.name for m in db.messages} == set(TIMING) | set(TIMING_EXTENDED)
    for name, (cycle_ms, send_type) in (TIMING | TIMING_EXTENDED).items():
        message = db.get_message_by_name(name)
        assert message.dbc.attributes['GenMsgCycleTime'].value == cycle_ms, name
        assert (message.cycle_time, message.send_type) == (cycle_ms, send_type), name
    text = default_dbc_path().read_text()
    assert 'BA_DEF_ BO_ "GenMsgCycleTime"' in text and 'BA_DEF_ "BusType"' in text


def test_every_enumeration_has_a_value_table() -> None:
    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    db.add_dbc_file(str(fault_injection_dbc_path()))
    for message in db.messages:
        for signal in message.signals:
            if signal.name in ('Counter', 'Checksum') or signal.scale != 1 \
                    or signal.length > 8:
                continue
            assert signal.choices, f'{message.name}.{signal.name} has no VAL_ table'
    state = db.get_message_by_name(STATUS).get_signal_by_name('ControllerState')
    assert dict(state.choices) == {0: 'Init', 1: 'Standby', 2: 'Running', 3: 'Fault'}
    fault = db.get_message_by_name(CONTROL).get_signal_by_name('Fault')
    assert {int(k) for k in fault.choices} == {int(f) for f in EmulatorFault}


def test_default_ids_coexist_with_canopen_devices() -> None:
    codec = ValveCodec(0, include_test_messages=True)
    used = {codec.frame_id(name, node) for name in TIMING.keys() | {CONTROL}
            for node in range(MAX_NODE_ID + 1)}
    assert used <= set(range(0x680, 0x6E0))
    assert not used & _canopen_ids()


def test_the_extended_ids_never_meet_an_11_bit_id() -> None:
    """ValveTelemetryMean: 29-bit ids 0x16900 + node, protected by a 4-byte id checksum."""
    codec = ValveCodec(0, include_test_messages=True)
    ids = {codec.frame_id(TELEMETRY_MEAN, node) for node in range(MAX_NODE_ID + 1)}
    assert ids == set(range(0x16900, 0x16910))
    msg = codec.encode(TELEMETRY_MEAN, {'CoilCurrentMean': 0.5, 'CoilVoltageMean': 12.0,
                                        'MeanInterval': 1e-3}, 3)
    assert msg.is_extended_id and codec.decode(msg).name == TELEMETRY_MEAN
    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    assert [m.name for m in db.messages if m.is_extended_frame] == [TELEMETRY_MEAN, DRIVE]
    drive = {codec.frame_id(DRIVE, node) for node in range(MAX_NODE_ID + 1)}
    assert drive == set(range(0x16910, 0x16920)) and not drive & ids
    msg = codec.encode(DRIVE, {'DriveModeActive': 1, 'CapacitorVoltage': 0.0,
                               'HoldingCurrent': 0.0, 'SupplyVoltageMeasured': 24.0}, 3)
    assert msg.is_extended_id and codec.decode(msg).name == DRIVE


def test_the_driver_never_loads_the_test_messages() -> None:
    codec = ValveCodec(0)
    assert codec.classify(ValveCodec(0, include_test_messages=True).frame_id(CONTROL)) is None
    with pytest.raises(KeyError):
        codec.frame_id(CONTROL)
    core = CanDriverCore(DriverConfig(interface='virtual', channel='dbc_test'))
    assert core.codec.classify(0x6D0) is None
    assert 'EmulatorControl' not in default_dbc_path().read_text()


def _crc8_table_reference(data: bytes) -> int:
    """The hand-written table CRC-8/SAE-J1850 the codec used before crccheck."""
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    crc = 0xFF
    for byte in data:
        crc = table[crc ^ byte]
    return crc ^ 0xFF


def test_crccheck_equals_the_old_implementation_on_random_frames() -> None:
    rng = random.Random(10)
    for _ in range(5000):
        frame = bytes(rng.randrange(256) for _ in range(9))   # 2 id bytes + data[0:7]
        assert crc8(frame) == _crc8_table_reference(frame), frame.hex()
    assert crc8(b'123456789') == _crc8_table_reference(b'123456789') == 0x4B


def test_pwm_frequency_limits_are_the_suites_one_pair() -> None:
    """DBC signal limits == MIN/MAX_PWM_FREQUENCY_HZ == what driver and simulator accept."""
    from valve_driver_pkg.driver.config import DriverConfig as Config
    from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ
    import dataclasses

    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    command = db.get_message_by_name(COMMAND).get_signal_by_name('PwmFrequency')
    assert (command.minimum, command.maximum) == (MIN_PWM_FREQUENCY_HZ, MAX_PWM_FREQUENCY_HZ)
    for name in (PERIOD, STATUS):
        active = db.get_message_by_name(name).get_signal_by_name('PwmFrequencyActive')
        assert active.maximum == MAX_PWM_FREQUENCY_HZ, name
    fields = {f.name: f for f in dataclasses.fields(Config)}
    for name in ('pwm_frequency_hz', 'max_pwm_frequency_hz'):
        assert fields[name].metadata['range'] == (MIN_PWM_FREQUENCY_HZ, MAX_PWM_FREQUENCY_HZ)
    from valve_model_pkg.nodes import simulator_node
    assert simulator_node.MAX_PWM_FREQUENCY_HZ == MAX_PWM_FREQUENCY_HZ
    assert simulator_node.MIN_PWM_FREQUENCY_HZ == MIN_PWM_FREQUENCY_HZ


def test_command_frame_carries_a_host_id() -> None:
    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    host = db.get_message_by_name(COMMAND).get_signal_by_name('HostId')
    assert (host.start, host.length, host.minimum, host.maximum) == (36, 4, 0, 15)


def test_the_drive_mode_is_a_command_signal_with_a_value_table() -> None:
    """The bench mode is a protocol matter, not an emulator flag."""
    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    mode = db.get_message_by_name(COMMAND).get_signal_by_name('DriveMode')
    assert (mode.start, mode.length, mode.minimum, mode.maximum) == (34, 2, 0, 1)
    assert dict(mode.choices) == {int(m): m.name.title() for m in DriveMode} \
        == {0: 'Normal', 1: 'Bench'}
    active = db.get_message_by_name(DRIVE).get_signal_by_name('DriveModeActive')
    assert dict(active.choices) == dict(mode.choices)
    drive = db.get_message_by_name(DRIVE)
    assert {s.name for s in drive.signals} >= {'HoldingCurrent', 'CapacitorVoltage',
                                               'SupplyVoltageMeasured'}
    assert drive.get_signal_by_name('HoldingCurrent').unit == 'A'
    assert 'bench' in db.get_message_by_name(COMMAND).get_signal_by_name(
        'DriveMode').comment.lower()


def test_overlapping_extended_id_ranges_are_refused(tmp_path) -> None:
    from valve_driver_pkg.errors import DbcError

    text = default_dbc_path().read_text().replace('2147576080', '2147576072')
    bad = tmp_path / 'overlap.dbc'
    bad.write_text(text)
    with pytest.raises(DbcError, match='overlap'):
        ValveCodec(0, bad)
