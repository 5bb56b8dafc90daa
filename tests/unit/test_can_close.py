"""Close semantics over CAN at the lowest PWM frequency (0.1 Hz): every stop path is bounded.

The emulator (the firmware reference) runs the model; its model time is what is measured.
Paths: the driver's command watchdog and ``deactivate`` (driver core and emulator in real
time on a private virtual bus, the emulator's own timeout off so the driver's path is the
one measured), and host loss (the host stops sending: the emulator's own command timeout;
model time stepped by the test). Bound: the coil is de-energised within one telemetry
period (1 ms) + 1 ms of the instant the controller has the reason to switch off.
"""
from __future__ import annotations

import itertools
import time

import can
import pytest
from suite_waits import SCHEDULING_ALLOWANCE_S, wait_until

from valve_driver_pkg.driver import CanDriverCore, DriverConfig
from valve_driver_pkg.emulator import ControllerEmulator, EmulatorConfig
from valve_driver_pkg.emulator.config import DEFAULT_COMMAND_TIMEOUT_S
from valve_driver_pkg.protocol import COMMAND, ValveCodec
from valve_model_pkg.model import ElectronicsConfig, ValveStepper, load_parameters

PARAMS = load_parameters()
FREQ_HZ = 0.1                  # the lowest PWM frequency the protocol carries
DUTY = 0.9
#: The coil must be off this soon after the controller's reason to switch off [s].
DEENERGISE_BOUND_S = 2e-3
_channels = itertools.count()


class RecordingStepper(ValveStepper):
    """The emulator's model, recording commands and samples with their model times."""

    def __init__(self) -> None:
        self.commands: list[tuple[float, float]] = []
        self.voltage_after: dict[float, float] = {}   # model time -> coil voltage after it
        self.samples: list = []
        super().__init__(PARAMS, ElectronicsConfig())

    def set_command(self, duty: float, pwm_frequency_hz: float) -> None:
        self.commands.append((self.t_s, float(duty)))
        super().set_command(duty, pwm_frequency_hz)
        # the coil voltage right after the command, at the same model time (the
        # telemetry samples may skip instants when the real-time loop stalls)
        self.voltage_after[self.t_s] = super().sample().coil_voltage_v

    def sample(self):
        s = super().sample()
        self.samples.append(s)
        return s

    def first_stop(self, after_s: float = 0.0) -> float:
        """Model time of the first duty-0 command after a non-zero one, after ``after_s``."""
        driving = False
        for t, duty in self.commands:
            if duty > 0.0:
                driving = True
            elif driving and t >= after_s:
                return t
        raise AssertionError(f'no stop in {self.commands[-5:]}')

    def off_after(self, t_stop: float) -> float:
        """Model time from ``t_stop`` to the coil voltage <= 0 (0: at the command)."""
        if self.voltage_after.get(t_stop, 1.0) <= 0.0:
            return 0.0
        for s in self.samples:
            if s.t_s >= t_stop and s.coil_voltage_v <= 0.0:
                return s.t_s - t_stop
        raise AssertionError('coil never de-energised')


class Rig:
    """Driver core + emulator in real time (emulator timeout off: the driver's path)."""

    def __init__(self, **driver) -> None:
        channel = f'close_test_{next(_channels)}'
        self.bus = can.Bus(interface='virtual', channel=channel)
        self.stepper = RecordingStepper()
        self.emu = ControllerEmulator(self.bus, self.stepper,
                                      EmulatorConfig(command_timeout_s=0.0))
        self.core = CanDriverCore(DriverConfig(interface='virtual', channel=channel, **driver))
        self.emu.start()
        self.core.open()
        self.core.activate()

    def open_valve(self) -> None:
        self.core.set_command(DUTY, FREQ_HZ)
        wait_until(lambda: self.emu.output_duty == pytest.approx(DUTY), what='duty at controller')
        t = self.emu.model_time_s
        wait_until(lambda: self.emu.model_time_s > t + 0.05, what='model time')
        last = self.stepper.samples[-1]
        assert last.duty == pytest.approx(DUTY) and last.coil_voltage_v > 0.0

    def close(self) -> None:
        self.core.close()
        self.emu.stop()
        self.bus.shutdown()


def test_driver_watchdog_closes_at_once_at_0_1_hz() -> None:
    rig = Rig(command_timeout_s=0.2)
    try:
        commanded = time.monotonic()
        rig.open_valve()
        t_open = next(t for t, duty in rig.stepper.commands if duty > 0.0)
        wait_until(lambda: rig.core.counters['watchdog_trips'] >= 1, what='watchdog')
        # seen tripped at this host time, so it tripped no later: never before its timeout
        # (a bound that holds however late the threads run)
        assert time.monotonic() - commanded >= 0.2
        wait_until(lambda: rig.emu.output_duty == 0.0, what='duty 0 at the controller')
        t_stop = rig.stepper.first_stop(t_open)
        wait_until(lambda: rig.emu.model_time_s > t_stop + 0.05, what='model time')
        off = rig.stepper.off_after(t_stop)
        assert off <= DEENERGISE_BOUND_S, off
        assert all(s.coil_voltage_v <= 0.0 for s in rig.stepper.samples if s.t_s > t_stop)
        # the emulator dates a frame by its model time when it handles it, late after a
        # stall of its own loop: in model time the stop follows the opening by the timeout
        # up to that lateness, within the scheduling allowance of a loaded machine
        assert 0.0 < t_stop - t_open <= 0.2 + SCHEDULING_ALLOWANCE_S
        last = rig.stepper.samples[-1]
        assert last.spool_position_m == 0.0 and last.duty == 0.0
    finally:
        rig.close()


def test_deactivate_closes_at_once_at_0_1_hz() -> None:
    rig = Rig(command_timeout_s=0.0)
    try:
        rig.open_valve()
        t_open = rig.stepper.commands[-1][0]
        assert rig.core.deactivate()
        wait_until(lambda: not rig.emu.command.enabled, what='disabled')
        t_stop = rig.stepper.first_stop(t_open)
        wait_until(lambda: rig.emu.model_time_s > t_stop + 0.05, what='model time')
        assert rig.stepper.off_after(t_stop) <= DEENERGISE_BOUND_S
        assert rig.stepper.samples[-1].spool_position_m == 0.0
    finally:
        rig.close()


def test_host_loss_closes_within_the_command_timeout_at_0_1_hz() -> None:
    """The host stops sending (killed): the emulator's own timeout, in its model time."""
    channel = f'close_test_{next(_channels)}'
    emu_bus = can.Bus(interface='virtual', channel=channel)
    host = can.Bus(interface='virtual', channel=channel)
    stepper = RecordingStepper()
    emu = ControllerEmulator(emu_bus, stepper, EmulatorConfig())
    codec = ValveCodec(0)
    try:
        assert emu.config.command_timeout_s == DEFAULT_COMMAND_TIMEOUT_S == 0.1
        t_last = 0.0
        for k in range(100):                       # 1 s of commands at 100 Hz, then none
            t_last = k * 0.01
            emu.step(t_last)
            host.send(codec.encode(COMMAND, {'Duty': DUTY, 'PwmFrequency': FREQ_HZ,
                                             'Enable': 1, 'ClearFaults': 0, 'HostId': 1}, k))
            emu.poll(0.5)
        assert stepper.samples[-1].coil_voltage_v > 0.0
        for k in range(1, 401):                    # 0.4 s of silence in 1 ms steps
            emu.step(t_last + k * 1e-3)
        t_stop = stepper.first_stop()
        assert t_stop == pytest.approx(t_last + DEFAULT_COMMAND_TIMEOUT_S, abs=1e-9)
        assert stepper.off_after(t_stop) <= DEENERGISE_BOUND_S
        off_total = stepper.off_after(t_last)
        assert off_total <= DEFAULT_COMMAND_TIMEOUT_S + DEENERGISE_BOUND_S, off_total
        closed = next(s.t_s for s in stepper.samples
                      if s.t_s > t_stop and s.spool_position_m == 0.0)
        assert closed - t_stop <= 0.010
    finally:
        emu_bus.shutdown()
        host.shutdown()
