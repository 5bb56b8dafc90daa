"""Streaming valve model for real-time use (simulator node, CAN emulator).

Command semantics (the suite's one definition; the CAN emulator and the trace runs use the
same kernel function, ``kernel._command``)
------------------------------------------------------------------------------------------
* **Duty 0 acts at once.** ``set_command(0, f)`` while a non-zero duty is in force ends
  the running main PWM high phase at the current model time: the chopper stops, the
  negative-voltage capacitor pulse starts, and the release then follows the physics
  (current decay, spring). ``sample().duty`` is 0 from that instant. Whatever the PWM
  frequency, the coil is de-energised at the command's model time (0 s of latency in the
  model; a real-time caller adds its own sampling delay).
* **Any other change waits for the next period start.** A non-zero duty, and any
  frequency (also the one given with duty 0), take effect at the start of the next main
  PWM period (the next rising-edge slot), so a running pulse is never cut short or
  stretched and each period has one consistent duty - the glitch-free update of a
  hardware PWM timer with shadow registers. The latency is at most one PWM period (20 ms at
  50 Hz). Periods tick from t = 0 (the first starts at t = 0 with the command given at
  construction, default duty 0); a stop does not move the period grid, so a later non-zero
  command starts at the next period start of the same grid (maps and identification,
  which never stop within a period, are unchanged).

``set_pressures`` acts at once (from the current time on). ``advance_to(t_s)`` integrates
up to ``t_s``; ``sample()`` reads the state at the current time without advancing.

Interval means
--------------
The kernel integrates the coil terminal current and voltage exactly with the state.
``sample()`` reports, besides the instantaneous values, their means over the interval
since the previous sampling instant (``coil_current_mean_a``, ``coil_voltage_mean_v``):
the first ``sample()`` (or :meth:`ValveStepper.interval_means`) at a model time later than
the previous one closes the interval; further calls at the same time return the same
means. A caller that samples once per published message (the simulator node, the lockstep
axis, the emulator's telemetry) thus publishes the exact mean since its previous message.
An empty interval (t = 0, right after :meth:`reset`) gives the instantaneous values.
"""
from __future__ import annotations

import math

import numpy as np

from .aot import backend as _backend, constants as _constants
from .constants import ATMOSPHERIC_PRESSURE_PA
from .electronics import ElectronicsConfig
from .parameters import ParameterError, ValveParameters
from .sample import ValveSample

__all__ = ['ValveSample', 'ValveStepper']

# The kernel's layout constants (D_*, Y_*, N_*), read without importing numba; the
# compiled functions come from _backend(): the ahead-of-time module or the jit (aot.py).
_k = _constants()


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
        self._kb = _backend()
        self._p = self._kb.derive_parameters(
            np.ascontiguousarray(params.to_vector(), dtype=np.float64))
        self._e = self._electronics.to_vector()
        self._out = np.zeros((0, _k.N_OUT))
        self._avg = np.zeros(0)
        self.reset()

    def __getstate__(self) -> dict:
        # the AOT module's functions do not pickle (its name is per kernel key): the
        # receiving process picks its own backend
        state = dict(self.__dict__)
        del state['_kb']
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._kb = _backend()

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
        self._d = self._kb.new_drive_state(self._supply_voltage, duty, 1.0 / freq, 0.0,
                                           p_sup, p_out, math.inf, 0.0)
        self._d[_k.D_DUTY] = duty
        self._pending = (duty, freq)
        # interval means: (t, integral of i, integral of v) at the start of the running
        # interval, and the means of the interval that ended at the start time
        self._iv_start = (0.0, 0.0, 0.0)
        self._iv_last: tuple[float, float] | None = None

    def set_command(self, duty: float, pwm_frequency_hz: float) -> None:
        """Command a duty cycle in [0, 1] and main PWM frequency in Hz.

        Duty 0 switches the coil off at once (the running high phase ends now); any other
        duty, and the frequency, take effect at the next main PWM period start
        (glitch-free, see the module doc).

        Raises
        ------
        ParameterError
            Duty outside [0, 1] or non-positive/non-finite frequency.
        """
        _check_command(duty, pwm_frequency_hz)
        self._kb.command(float(self._d[_k.D_T]), self._d, self._e, float(duty),
                         1.0 / float(pwm_frequency_hz))
        self._pending = (float(duty), float(pwm_frequency_hz))

    @property
    def next_period_start_s(self) -> float:
        """Model time of the next main PWM period start, s (where a command takes effect)."""
        return float(self._d[_k.D_NEXT_BOUNDARY])

    def set_electronics(self, electronics: ElectronicsConfig) -> None:
        """Switch the drive electronics at the current model time (a controller's drive mode).

        The caller chooses the instant (the CAN emulator: a period start, or at once while
        duty 0 is in force). The state is kept: a capacitor pulse already running decays as
        it started. If the main PWM is high, its high phase restarts under the new
        electronics as at a rising edge (without current control: the supply from now on;
        with it: a boost, then the chopper); the capacitor keeps charging from its edge. A
        low main PWM stays low, so a switch never energises the coil by itself.
        """
        self._electronics = electronics
        self._e = electronics.to_vector()
        d = self._d
        if d[_k.D_MAIN_ON] != 0.0:
            vc_on, t_on = d[_k.D_VC_ON], d[_k.D_T_ON]
            self._kb.rising_edge(float(d[_k.D_T]), self._y, self._p, d, self._e)
            d[_k.D_VC_ON], d[_k.D_T_ON] = vc_on, t_on

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
        self._kb.advance(self._p, self._e, self._y, self._d, float(t_s), self._h[0],
                         self._h[1], self._out, self._avg)

    def interval_means(self) -> tuple[float, float]:
        """Mean coil current (A) and voltage (V) since the previous sampling instant.

        Exact: the kernel's integrals of the terminal current and voltage (the same as
        :func:`~valve_model_pkg.model.simulate_trace_batch` with ``'interval_mean'``),
        divided by the interval. Ends the interval at the current model time (a new one
        starts); a second call at the same time returns the same means. With no interval
        yet (t = 0, after :meth:`reset`) the instantaneous values.

        Returns
        -------
        tuple of float
            ``(coil_current_mean_a, coil_voltage_mean_v)``.
        """
        d = self._d
        t = float(d[_k.D_T])
        t0, qi0, qv0 = self._iv_start
        if t > t0:
            width = t - t0
            self._iv_last = ((float(d[_k.D_QI]) - qi0) / width,
                             (float(d[_k.D_QV]) - qv0) / width)
            self._iv_start = (t, float(d[_k.D_QI]), float(d[_k.D_QV]))
        if self._iv_last is None:
            phase = int(d[_k.D_PHASE])
            return (float(self._kb.terminal_current(t, self._y, phase, self._p, d, self._e)),
                    float(self._kb.voltage(t, phase, d, self._e)))
        return self._iv_last

    def sample(self) -> ValveSample:
        """The valve state at the current model time, with the interval means.

        The means cover the interval since the previous sampling instant and end it (see
        :meth:`interval_means`); the model state is not advanced.
        """
        i_mean, v_mean = self.interval_means()
        d, y = self._d, self._y
        t = float(d[_k.D_T])
        phase = int(d[_k.D_PHASE])
        volt = float(self._kb.voltage(t, phase, d, self._e))
        cur = float(self._kb.terminal_current(t, y, phase, self._p, d, self._e))
        x_avg = float(d[_k.D_XAVG])
        p_sup = float(d[_k.D_PSUP])
        p_out = float(d[_k.D_POUT])
        flow = _mass_flow_scalar(self._kb, x_avg, p_sup, p_out, self._params)
        return ValveSample(
            t_s=t, coil_voltage_v=volt, coil_current_a=cur,
            spool_position_m=float(y[_k.Y_X]), spool_velocity_m_s=float(y[_k.Y_V]),
            position_avg_m=x_avg, mass_flow_kg_s=flow, duty=float(d[_k.D_DUTY]),
            pwm_frequency_hz=float(1.0 / d[_k.D_PERIOD]), supply_pressure_pa=p_sup,
            output_pressure_pa=p_out, coil_temperature_rise_k=float(y[_k.Y_DT]),
            coil_current_mean_a=i_mean, coil_voltage_mean_v=v_mean)


def _mass_flow_scalar(kb, position_m: float, supply_pressure_pa: float,
                      output_pressure_pa: float, params: ValveParameters) -> float:
    """``orifice.orifice_mass_flow_scalar`` on the backend's compiled eq. (12), kg/s.

    The same arithmetic and the same compiled ``_mass_flow``, so the same number; here
    because orifice.py imports numba at module level.
    """
    up = supply_pressure_pa + ATMOSPHERIC_PRESSURE_PA
    down = output_pressure_pa + ATMOSPHERIC_PRESSURE_PA
    sign = 1.0
    if down > up:
        up, down, sign = down, up, -1.0
    return sign * float(kb.mass_flow(position_m, up, down, params.discharge_coefficient,
                                     params.orifice_area_gradient_m,
                                     params.supply_temperature_k,
                                     params.gas_constant_j_per_kg_k,
                                     params.heat_capacity_ratio))


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
