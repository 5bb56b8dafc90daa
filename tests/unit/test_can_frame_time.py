"""States are stamped with the time their frame was on the bus, not when the host got to it:
the emulator stamps its frames on its own model clock, and the driver keeps a frame's
timestamp when it is this clock's."""
from __future__ import annotations

import time

import can
import numpy as np
import pytest

from valve_driver_pkg.canbus.frame_time import CLOCK_APART_S, frame_time_s
from valve_driver_pkg.driver import CanDriverCore, DriverConfig
from valve_driver_pkg.emulator import ControllerEmulator, EmulatorConfig
from valve_driver_pkg.protocol import TELEMETRY, ValveCodec
from valve_model_pkg.model import ElectronicsConfig, ValveStepper, load_parameters
from valve_model_pkg.model.sample import ValveSample

PARAMS = load_parameters()


@pytest.mark.parametrize('timestamp, expected', [
    (1000.0 - 0.25, 1000.0 - 0.25),         # on the bus a quarter second ago: kept
    (1000.0, 1000.0),
    (0.0, 1000.0),                          # no timestamp
    (1000.0 + 0.01, 1000.0 + 0.01),         # a sender's clock a little ahead
    (1000.0 - CLOCK_APART_S - 1.0, 1000.0),  # an adapter counting from its own start
    (1000.0 + CLOCK_APART_S + 1.0, 1000.0),
    (float('nan'), 1000.0),                 # garbage from an interface: the receipt
    (float('inf'), 1000.0),
    (-5.0, 1000.0),
])
def test_frame_time_is_the_frames_own_when_it_is_this_clocks(timestamp, expected) -> None:
    assert frame_time_s(timestamp, 1000.0) == expected


class _StallingBus(can.BusABC):
    """Collects what the emulator sends; sleeps ``stall_s`` once in the send of the first
    telemetry frame at or after ``stall_after`` frames (the loop is descheduled)."""

    def __init__(self, stall_after: int, stall_s: float) -> None:
        self.sent: list[can.Message] = []
        self._stall_after, self._stall_s = stall_after, stall_s
        self._telemetry_id = ValveCodec(0).frame_id(TELEMETRY)
        self._telemetry = 0
        super().__init__(channel='stall')

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)
        if msg.arbitration_id == self._telemetry_id:
            self._telemetry += 1
            if self._telemetry == self._stall_after:
                time.sleep(self._stall_s)

    def _recv_internal(self, timeout: float | None):
        time.sleep(timeout or 0.0)
        return None, False


def test_the_emulator_stamps_frames_on_its_model_clock_through_a_stall() -> None:
    bus = _StallingBus(stall_after=50, stall_s=0.04)
    emu = ControllerEmulator(bus, ValveStepper(PARAMS, ElectronicsConfig()), EmulatorConfig())
    before = time.time()
    emu.run(duration_s=0.2)
    after = time.time()
    telemetry_id = ValveCodec(0).frame_id(TELEMETRY)
    stamps = np.array([m.timestamp for m in bus.sent if m.arbitration_id == telemetry_id])
    assert stamps.size > 100
    assert before <= stamps[0] and stamps[-1] <= after
    steps = np.diff(stamps) / 1e-3
    # every frame sits on the 1 kHz grid of the model, before and after the stall (to
    # 1 us: the resolution of a float64 epoch time is 0.24 us) ...
    assert np.allclose(steps, np.round(steps), atol=1e-3), steps
    # ... and the stall is a gap of skipped instants (counted), not a bunch of frames
    assert emu.stats['overruns'] > 0
    assert steps.max() >= 2 and steps.min() > 1 - 1e-3


def _telemetry(codec: ValveCodec, counter: int, timestamp: float) -> can.Message:
    return codec.encode(TELEMETRY, {
        'CoilCurrent': 0.5, 'CoilVoltage': 24.0, 'SpoolPosition': 1e-4, 'Enabled': 1,
        'PositionValid': 1, 'FaultActive': 0, 'CommandTimeout': 0}, counter,
        timestamp=timestamp)


def test_the_driver_stamps_a_state_with_its_frames_time() -> None:
    states: list[ValveSample] = []
    core = CanDriverCore(DriverConfig(interface='virtual', channel='frame_time_core'),
                         on_state=states.append)
    core.activate()
    codec = ValveCodec(0)
    on_bus = time.time() - 0.05
    core.handle_frame(_telemetry(codec, 0, on_bus))
    core.handle_frame(_telemetry(codec, 1, on_bus + 1e-3))
    core.handle_frame(_telemetry(codec, 2, 0.0))   # an interface without timestamps
    handled = time.time()
    assert [s.t_s for s in states[:2]] == [on_bus, on_bus + 1e-3]
    assert on_bus + 0.05 <= states[2].t_s <= handled


def test_on_the_simulation_clock_frames_carry_and_states_keep_the_model_instant() -> None:
    # the emulator on the simulation clock stamps each frame with its model instant ...
    bus = _StallingBus(stall_after=10 ** 9, stall_s=0.0)
    emu = ControllerEmulator(bus, ValveStepper(PARAMS, ElectronicsConfig()), EmulatorConfig())
    emu.model_time_stamps = True
    for k in range(1, 21):
        emu.step(k * 1e-3, 0)
    telemetry_id = ValveCodec(0).frame_id(TELEMETRY)
    stamps = [m.timestamp for m in bus.sent if m.arbitration_id == telemetry_id]
    assert stamps == pytest.approx([k * 1e-3 for k in range(21)], abs=1e-12)
    # ... and the driver on that clock keeps it; a wall-clock stamp is another clock's
    states: list[ValveSample] = []
    core = CanDriverCore(DriverConfig(interface='virtual', channel='frame_time_sim'),
                         on_state=states.append)
    sim_now = 2.0105                        # the node's clock: /clock came a little late
    core.frame_clock = lambda: sim_now
    core.activate()
    codec = ValveCodec(0)
    core.handle_frame(_telemetry(codec, 0, 2.011))
    core.handle_frame(_telemetry(codec, 1, time.time()))
    assert [s.t_s for s in states] == [2.011, sim_now]
