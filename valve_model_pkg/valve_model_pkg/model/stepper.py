"""Streaming valve model for real-time use (simulator node, CAN emulator).

Command semantics
-----------------
``set_command(duty, pwm_frequency_hz)`` does not act at once: the new duty and frequency
take effect at the start of the next main PWM period (the next rising-edge slot), so a
running pulse is never cut short or stretched and each period has one consistent duty -
the glitch-free update of a hardware PWM timer with shadow registers. The latency is
therefore at most one PWM period (20 ms at 50 Hz). Periods tick from t = 0 (the first
starts at t = 0 with the command given at construction, default duty 0).

``set_pressures`` acts at once (from the current time on). ``advance_to(t_s)`` integrates
up to ``t_s``; ``sample()`` reads the state at the current time without advancing.
"""
from __future__ import annotations

import math

import numpy as np

from . import kernel as _k
from .electronics import ElectronicsConfig
from .orifice import orifice_mass_flow_scalar
from .parameters import ParameterError, ValveParameters
from .sample import ValveSample

__all__ = ['ValveSample', 'ValveStepper']


class ValveStepper:
    """Streaming model: command, advance in time, sample.

    Parameters
    ----------
    params : ValveParameters
    electronics : ElectronicsConfig, optional
        Default ``ElectronicsConfig()`` (the real valve's electronics).
    supply_voltage_v : float
        Driver supply voltage, V.
    duty : float
        Initial duty cycle in [0, 1].
    pwm_frequency_hz : float
        Initial main PWM frequency, Hz.
    supply_pressure_pa, output_pressure_pa : float
        Initial gauge pressures, Pa.
    h_free_s, h_stop_s : float
        Maximum RK4 steps, s.

    Examples
    --------
    >>> stepper = ValveStepper(load_parameters())
    >>> stepper.set_command(0.4, 50.0)
    >>> stepper.advance_to(0.1)
    >>> sample = stepper.sample()
    """

    def __init__(self, params: ValveParameters, electronics: ElectronicsConfig | None = None,
                 supply_voltage_v: float = 24.0, *, duty: float = 0.0,
                 pwm_frequency_hz: float = 50.0, supply_pressure_pa: float = 4.0e5,
                 output_pressure_pa: float = 0.0, h_free_s: float = _k.DEFAULT_H_FREE_S,
                 h_stop_s: float = _k.DEFAULT_H_STOP_S) -> None:
        if not math.isfinite(supply_voltage_v):
            raise ParameterError(f'supply_voltage_v must be finite, got {supply_voltage_v!r}')
        _check_command(duty, pwm_frequency_hz)
        _check_pressures(supply_pressure_pa, output_pressure_pa)
        self._params = params
        self._electronics = electronics if electronics is not None else ElectronicsConfig()
        self._supply_voltage = float(supply_voltage_v)
        self._init = (float(duty), float(pwm_frequency_hz), float(supply_pressure_pa),
                      float(output_pressure_pa))
        self._h = (float(h_free_s), float(h_stop_s))
        self._p = _k.derive_parameters(params.to_vector())
        self._e = self._electronics.to_vector()
        self._out = np.zeros((0, _k.N_OUT))
        self._avg = np.zeros(0)
        self.reset()

    @property
    def params(self) -> ValveParameters:
        """The parameter set."""
        return self._params

    @property
    def electronics(self) -> ElectronicsConfig:
        """The electronics configuration."""
        return self._electronics

    @property
    def t_s(self) -> float:
        """Current model time, s."""
        return float(self._d[_k.D_T])

    def reset(self) -> None:
        """Back to t = 0, valve closed at rest, initial command and pressures."""
        duty, freq, p_sup, p_out = self._init
        self._y = np.zeros(_k.N_Y)
        self._d = _k.new_drive_state(self._supply_voltage, duty, 1.0 / freq, 0.0, p_sup,
                                     p_out)
        self._d[_k.D_DUTY] = duty
        self._pending = (duty, freq)

    def set_command(self, duty: float, pwm_frequency_hz: float) -> None:
        """Command a duty cycle in [0, 1] and main PWM frequency in Hz.

        Takes effect at the next main PWM period start (glitch-free, see module doc).

        Raises
        ------
        ParameterError
            Duty outside [0, 1] or non-positive/non-finite frequency.
        """
        _check_command(duty, pwm_frequency_hz)
        self._d[_k.D_PEND_DUTY] = float(duty)
        self._d[_k.D_PEND_PERIOD] = 1.0 / float(pwm_frequency_hz)
        self._pending = (float(duty), float(pwm_frequency_hz))

    def set_pressures(self, supply_pa: float, output_pa: float = 0.0) -> None:
        """Set the supply and output gauge pressures in Pa (effective immediately)."""
        _check_pressures(supply_pa, output_pa)
        self._d[_k.D_PSUP] = float(supply_pa)
        self._d[_k.D_POUT] = float(output_pa)

    def advance_to(self, t_s: float) -> None:
        """Integrate up to model time ``t_s`` in s (no-op if not later than now).

        Raises
        ------
        ParameterError
            If ``t_s`` is not finite.
        """
        if not math.isfinite(t_s):
            raise ParameterError(f't_s must be finite, got {t_s!r}')
        if t_s <= self._d[_k.D_T]:
            return
        _k.advance(self._p, self._e, self._y, self._d, float(t_s), self._h[0], self._h[1],
                   self._out, self._avg)

    def sample(self) -> ValveSample:
        """The valve state at the current model time."""
        d, y = self._d, self._y
        t = float(d[_k.D_T])
        phase = int(d[_k.D_PHASE])
        volt = float(_k._voltage(t, phase, d, self._e))
        cur = float(_k._terminal_current(t, y, phase, self._p, d, self._e))
        x_avg = float(d[_k.D_XAVG])
        p_sup = float(d[_k.D_PSUP])
        p_out = float(d[_k.D_POUT])
        flow = orifice_mass_flow_scalar(x_avg, p_sup, p_out, self._params)
        return ValveSample(
            t_s=t, coil_voltage_v=volt, coil_current_a=cur,
            spool_position_m=float(y[_k.Y_X]), spool_velocity_m_s=float(y[_k.Y_V]),
            position_avg_m=x_avg, mass_flow_kg_s=flow, duty=float(d[_k.D_DUTY]),
            pwm_frequency_hz=float(1.0 / d[_k.D_PERIOD]), supply_pressure_pa=p_sup,
            output_pressure_pa=p_out, coil_temperature_rise_k=float(y[_k.Y_DT]))


def _check_command(duty: float, pwm_frequency_hz: float) -> None:
    if not isinstance(duty, (int, float, np.number)) or not math.isfinite(duty) \
            or not 0.0 <= duty <= 1.0:
        raise ParameterError(f'duty must be in [0, 1], got {duty!r}')
    if not isinstance(pwm_frequency_hz, (int, float, np.number)) \
            or not math.isfinite(pwm_frequency_hz) or pwm_frequency_hz <= 0.0:
        raise ParameterError(f'pwm_frequency_hz must be positive, got {pwm_frequency_hz!r}')


def _check_pressures(supply_pa: float, output_pa: float) -> None:
    for name, value in (('supply_pa', supply_pa), ('output_pa', output_pa)):
        if not isinstance(value, (int, float, np.number)) or not math.isfinite(value) \
                or value < -1.0e5:
            raise ParameterError(
                f'{name} must be a finite gauge pressure above -1 bar, got {value!r}')
