"""Settings and state names of the emulated controller firmware (ROS-free).

Drive modes (``ValveCommand.DriveMode``): the emulated hardware's own electronics (the
stepper's ``ElectronicsConfig`` at construction; ``valve_controller_emulator``'s
``--no-current-control`` / ``--no-capacitor`` describe hardware built without them) are
the ``normal`` mode; :func:`bench_electronics` derives the ``bench`` mode from them.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

__all__ = ['StepperLike', 'ControllerState', 'EmulatorConfig', 'UNKNOWN_INJECTED_ID',
           'FLAG_HOLD_S', 'PERIOD_REFRESH_S', 'MIN_PRESSURE_PA', 'DEFAULT_COMMAND_TIMEOUT_S',
           'clamp', 'bench_electronics']

#: Id of the frames the ``UNKNOWN_ID`` fault puts on the bus (outside every protocol range).
UNKNOWN_INJECTED_ID = 0x5A5
#: How long a command fault flag (checksum, counter, range) stays set after the event [s].
FLAG_HOLD_S = 1.0
#: ValvePeriod is repeated at least this often even when nothing changed [s].
PERIOD_REFRESH_S = 0.1
#: The controller's own command timeout (host loss) [s]: while enabled, no valid
#: ``ValveCommand`` for this long switches the coil off at once (``CommandTimeout``) until
#: the next valid command. The driver sends at 100 Hz, so 10 commands in a row must be lost.
#: The coil is off within this time plus one telemetry period (docs/safety.md).
DEFAULT_COMMAND_TIMEOUT_S = 0.1
#: Lowest gauge pressure the model accepts [Pa] (lower values are clamped).
MIN_PRESSURE_PA = -1.0e5


def clamp(value: float, low: float, high: float) -> float:
    """``value`` limited to ``[low, high]``."""
    return low if value < low else high if value > high else value


def bench_electronics(normal):
    """The ``bench`` drive mode of hardware whose normal electronics are ``normal``.

    Boost, holding-current chopper and capacitor release pulse bypassed: the coil sees the
    supply voltage for the whole main PWM high phase (as long as duty = 1) and 0 V in the
    low phase, a bare-coil voltage step. Every other setting stays.

    Parameters
    ----------
    normal : ElectronicsConfig
        The electronics of the ``normal`` mode.

    Returns
    -------
    ElectronicsConfig
    """
    return dataclasses.replace(normal, current_control=False, negative_voltage=False)


class StepperLike(Protocol):
    """What the emulator needs of ``valve_model_pkg.model.ValveStepper``."""

    def set_command(self, duty: float, pwm_frequency_hz: float) -> None: ...
    # optional (drive modes; without them the emulator stays in the normal mode):
    # ``electronics`` (ElectronicsConfig), ``set_electronics(config)``,
    # ``next_period_start_s`` (model time of the next main PWM period start, s)
    def set_pressures(self, supply_pa: float, output_pa: float) -> None: ...
    def advance_to(self, t_s: float) -> None: ...
    def sample(self): ...
    def interval_means(self) -> tuple[float, float]: ...   # optional (sampled values else)
    def reset(self) -> None: ...


class ControllerState:
    """Values of ``ValveStatus.ControllerState``."""

    INIT = 0       # no command received yet
    STANDBY = 1    # disabled or watchdog-closed
    RUNNING = 2    # driving the valve
    FAULT = 3      # a latched fault keeps the output off


@dataclass(frozen=True)
class EmulatorConfig:
    """Firmware settings of the emulated controller.

    Attributes
    ----------
    node_id : int
        Node id (frame ids = DBC ids + node id).
    telemetry_rate_hz : float
        ``ValveTelemetry`` rate [Hz].
    status_rate_hz : float
        ``ValveStatus`` heartbeat rate [Hz].
    command_timeout_s : float
        Firmware command watchdog [s]; 0 disables it.
    position_estimate : bool
        Report the spool position (``PositionValid=1``); false models a controller
        without an estimator.
    fault_injection : bool
        Obey ``EmulatorControl`` frames (fault injection over the bus). Off by default:
        anyone on the bus could otherwise switch faults; ignored frames are counted
        (``stats['control_frames_ignored']``). The in-process :meth:`inject` API and
        ``--fault`` schedules work either way (they are the operator's own choice).
    supply_voltage_v : float
        Drive supply voltage reported in the heartbeat and in ``ValveDrive`` [V] (the
        emulated hardware's supply; the model's is set where the stepper is built).
    overcurrent_a : float
        Coil current above which the overcurrent fault latches [A].
    max_burst : int
        In real time, the most telemetry frames sent at once after a stall; beyond it the
        frames are skipped (the counter still advances, so the host sees the loss).
    current_noise_a : float
        Standard deviation of the current ADC's noise on the reported coil current and its
        interval mean [A] (0: an ideal ADC). A real controller's current has noise; a
        noise-free record makes every residual smooth, so an identification counts few
        independent samples in it (valve_bench_loop uses 2 mA).
    noise_seed : int
        Seed of that noise (reproducible runs).
    """

    node_id: int = 0
    telemetry_rate_hz: float = 1000.0
    status_rate_hz: float = 10.0
    command_timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S
    position_estimate: bool = True
    fault_injection: bool = False
    supply_voltage_v: float = 24.0
    overcurrent_a: float = 6.0
    max_burst: int = 5
    current_noise_a: float = 0.0
    noise_seed: int = 0

    def __post_init__(self) -> None:
        if not 1.0 <= self.telemetry_rate_hz <= 10_000.0:
            raise ValueError(f'telemetry_rate_hz {self.telemetry_rate_hz!r} outside [1, 10000]')
        if not 0.1 <= self.status_rate_hz <= 1000.0:
            raise ValueError(f'status_rate_hz {self.status_rate_hz!r} outside [0.1, 1000]')
        if not 0.0 <= self.current_noise_a <= 0.5:
            raise ValueError(f'current_noise_a {self.current_noise_a!r} outside [0, 0.5] A')
        if self.command_timeout_s < 0.0:
            raise ValueError(f'command_timeout_s {self.command_timeout_s!r} is negative')
