"""The device driver's bus: error passive and bus-off reported, the bus restarted with a
bounded back-off, and the candump log of every frame (``log_frames_file``).

The bus is python-can's virtual bus whose controller state (python-can's ``bus.state``)
the test sets, as a CAN adapter reports it; the expected back-off is the rule stated in
the driver's docs (``reopen_period_s`` x 2^k, k the restarts in a row, the factor at most
16, no restart before a bus-off has lasted 0.2 s), written here from that rule.
"""
from __future__ import annotations

import itertools
import math
import time

import can
import pytest
from can.interfaces.virtual import VirtualBus
from suite_waits import wait_until

from valve_driver_pkg.devices.base import DeviceProtocol, DeviceReading, FrameOutcome
from valve_driver_pkg.devices.core import DeviceDriverCore
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Level
from valve_driver_pkg.driver.frame_log import FrameLog

REOPEN_PERIOD_S = 0.05
BUS_OFF_RESTART_S = 0.2          # docs/safety.md: a bus-off this long is restarted
MAX_FACTOR = 16
_channels = itertools.count()


class StateBus(VirtualBus):
    """A virtual bus whose controller state the test sets."""

    def __init__(self, channel: str, controller: dict) -> None:
        super().__init__(channel=channel)
        self._controller = controller

    @property
    def state(self) -> can.BusState:
        return self._controller['state']

    @state.setter
    def state(self, value: can.BusState) -> None:
        self._controller['state'] = value


class OneFrame(DeviceProtocol):
    """A device protocol of one command frame and no device frames (never lost)."""

    name = 'test'

    def __init__(self) -> None:
        super().__init__('test device', 0.01, math.inf)

    def command_frames(self, duty: float, enable: bool) -> list[can.Message]:
        return [can.Message(arbitration_id=0x123, is_extended_id=False,
                            data=bytes([round(duty * 100)]))]


class Reporting(OneFrame):
    """A device whose frames 0x321 report the coil current in mA (byte 0), every 10 s."""

    def __init__(self) -> None:
        DeviceProtocol.__init__(self, 'test device', 0.01, 10.0)

    def on_frame(self, msg: can.Message) -> FrameOutcome:
        if msg.arbitration_id != 0x321:
            return FrameOutcome()
        return FrameOutcome(True, DeviceReading(coil_current_a=msg.data[0] / 1000.0))


class Rig:
    """The core on a StateBus; every bus the core opens is recorded with the back-off in
    force when it was opened."""

    def __init__(self, protocol: DeviceProtocol | None = None) -> None:
        self.channel = f'device_bus_{next(_channels)}'
        self.controller = {'state': can.BusState.ACTIVE}
        self.opens: list[tuple[float, float]] = []    # (monotonic, back-off in force)
        self.states = []
        self.core = DeviceDriverCore(
            DriverConfig(protocol='dbc', interface='virtual', channel=self.channel,
                         reopen_period_s=REOPEN_PERIOD_S, command_timeout_s=0.0),
            protocol or OneFrame(), bus_factory=self._open, on_state=self.states.append)
        self.core.open()
        self.core.activate()

    def _open(self, interface, channel, bitrate, connect_timeout=0.0) -> can.BusABC:
        backoff = (self.bus_values()['restart_backoff_s'] if self.opens else 0.0)
        self.opens.append((time.monotonic(), backoff))
        return StateBus(channel, self.controller)

    def bus_status(self):
        return next(r for r in self.core.report() if r.name == 'CAN bus')

    def bus_values(self) -> dict:
        return self.bus_status().values

    def close(self) -> None:
        self.core.close()


@pytest.fixture
def rig():
    rig = Rig()
    yield rig
    rig.close()


def test_error_passive_is_a_warning_until_the_bus_is_active_again(rig) -> None:
    rig.controller['state'] = can.BusState.PASSIVE
    wait_until(lambda: rig.bus_status().level is Level.WARN, what='CAN bus WARN')
    status = rig.bus_status()
    assert 'error passive' in status.message
    assert status.values['error_passive_events'] == 1
    rig.controller['state'] = can.BusState.ACTIVE
    wait_until(lambda: rig.bus_status().level is Level.OK, what='CAN bus OK again')
    assert rig.bus_values()['bus_recoveries'] == 1
    assert len(rig.opens) == 1                   # error passive: no restart


def test_a_bus_stuck_in_bus_off_is_restarted_with_a_bounded_back_off(rig) -> None:
    rig.controller['state'] = can.BusState.ERROR
    wait_until(lambda: rig.bus_status().level is Level.ERROR, what='CAN bus ERROR')
    assert 'bus-off' in rig.bus_status().message
    wait_until(lambda: len(rig.opens) >= 7, what='six restarts')
    rig.controller['state'] = can.BusState.ACTIVE
    restarts = rig.opens[1:7]
    expected = [REOPEN_PERIOD_S * min(2 ** k, MAX_FACTOR) for k in range(1, 6)]
    # the back-off in force at each restart after the first: doubling, then capped
    assert [b for _, b in restarts[1:]] == pytest.approx(expected)
    for (t0, _), (t1, backoff) in zip(restarts, restarts[1:]):
        assert t1 - t0 >= max(backoff, BUS_OFF_RESTART_S) - 1e-3, (t1 - t0, backoff)
    wait_until(lambda: rig.bus_status().level is Level.OK, what='CAN bus OK again')
    values = rig.bus_values()
    assert values['bus_off_events'] >= 6 and values['bus_restarts'] >= 6
    # a bus that has worked for the longest back-off starts again from the shortest
    wait_until(lambda: rig.bus_values()['restarts_in_row'] == 0, what='back-off reset')
    n = len(rig.opens)
    rig.controller['state'] = can.BusState.ERROR
    wait_until(lambda: len(rig.opens) > n and rig.bus_values()['restarts_in_row'] == 1,
               what='a restart after the reset')
    assert rig.bus_values()['restart_backoff_s'] == pytest.approx(2 * REOPEN_PERIOD_S)
    rig.controller['state'] = can.BusState.ACTIVE


def test_a_frame_older_than_the_silence_limit_is_stale_not_a_state() -> None:
    rig = Rig(Reporting())
    try:
        def frame(ma: int, age_s: float) -> can.Message:
            return can.Message(timestamp=time.time() - age_s, arbitration_id=0x321,
                               is_extended_id=False, data=bytes([ma]))
        rig.core.handle_frame(frame(40, 0.0))
        rig.core.handle_frame(frame(41, 31.0))     # limit: 3 periods of 10 s
        rig.core.handle_frame(frame(42, 7200.0))   # another clock: not judged
        assert [round(s.coil_current_a * 1000) for s in rig.states] == [40, 42]
        device = next(r for r in rig.core.report() if r.name == 'device')
        assert device.values['stale_frames'] == 1
        assert device.level is Level.WARN and 'older than 30000 ms' in device.message
    finally:
        rig.close()


def test_frame_log_is_candump_read_back_by_python_can(tmp_path) -> None:
    path = tmp_path / 'sub' / 'bus.log'
    log = FrameLog(path, channel='127.0.0.1:29536', flush_period_s=0.0)
    frames = [can.Message(timestamp=1000.5, arbitration_id=0x205, is_extended_id=False,
                          data=bytes([0xE8, 0x03])),
              can.Message(timestamp=1000.6, arbitration_id=0x18FF2021, is_extended_id=True,
                          data=bytes(range(8))),
              can.Message(timestamp=1000.7, arbitration_id=0x705, is_extended_id=False,
                          data=b'')]
    log.write(frames[0], received=False)
    log.write(frames[1], received=True)
    log.write(frames[2], received=True)
    # flushed per frame: readable while the driver still writes
    assert len(path.read_text().splitlines()) == 3
    log.close()
    log.close()                                   # idempotent
    back = list(can.LogReader(str(path)))
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in back] == \
        [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in frames]
    assert [m.timestamp for m in back] == pytest.approx([1000.5, 1000.6, 1000.7])
    assert [m.is_rx for m in back] == [False, True, True]
    # one token per channel: no ':' or spaces in the candump line
    assert path.read_text().split()[1] == '127_0_0_1_29536'
