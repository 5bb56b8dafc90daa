"""The valve behind a stand-in device's output: the suite's model in wall-clock time.

A stand-in device sets a duty (and, where its protocol carries one, a PWM frequency) on
its output and reads back the coil current and the spool position, as its firmware would
from its current sense and position sensor. :class:`ValvePlant` runs
:class:`~valve_model_pkg.model.ValveStepper` so that model time follows the monotonic
clock since start; it is thread-safe.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from valve_model_pkg.model import ValveStepper, load_parameters

__all__ = ['ValvePlant', 'PlantReading']


@dataclass(frozen=True, slots=True)
class PlantReading:
    """The output's state now: duty in force, coil current [A], spool position [m] and its
    mean over the last complete PWM period [m] (0 before the first)."""

    duty: float
    coil_current_a: float
    spool_position_m: float
    position_avg_m: float


class ValvePlant:
    """The valve model run in real time behind a device output.

    Parameters
    ----------
    pwm_frequency_hz : float
        The output's PWM frequency until :meth:`set_output` gives another [Hz].
    params_file : str
        Valve parameter YAML; empty = the model's default set.
    """

    def __init__(self, pwm_frequency_hz: float = 50.0, params_file: str = '') -> None:
        self._stepper = ValveStepper(load_parameters(params_file or None),
                                     pwm_frequency_hz=pwm_frequency_hz)
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._duty = 0.0
        self._pwm_hz = float(pwm_frequency_hz)

    def set_output(self, duty: float, pwm_frequency_hz: float | None = None) -> None:
        """Drive the output at ``duty`` in [0, 1] (clamped); 0 switches the coil off at once."""
        duty = min(max(float(duty), 0.0), 1.0)
        with self._lock:
            self._advance()
            if pwm_frequency_hz:
                self._pwm_hz = float(pwm_frequency_hz)
            if duty != self._duty or pwm_frequency_hz:
                self._stepper.set_command(duty, self._pwm_hz)
            self._duty = duty

    @property
    def duty(self) -> float:
        """The duty the output is driven at."""
        return self._duty

    def read(self) -> PlantReading:
        """Advance the model to now and read the output."""
        with self._lock:
            self._advance()
            sample = self._stepper.sample()
        return PlantReading(self._duty, float(sample.coil_current_a),
                            float(sample.spool_position_m), float(sample.position_avg_m))

    def _advance(self) -> None:
        self._stepper.advance_to(time.monotonic() - self._t0)
