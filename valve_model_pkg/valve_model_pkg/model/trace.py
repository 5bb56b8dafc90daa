"""Batches of parameter sets under an arbitrary input trace: the model's general entry point.

:func:`simulate_trace_batch` simulates many parameter sets (one run each, in parallel)
under one :class:`InputTrace` and samples them at given times:

* ``InputTrace.coil_voltage(t_s, v)``: the terminal voltage of the bare coil (a bench
  supply, a measured voltage column). The drive electronics are not involved.
* ``InputTrace.pwm_commands(t_s, duty, pwm_frequency_hz, supply_voltage_v)``: main PWM
  commands through the drive electronics (boost, chopper with PI holding current,
  negative-voltage capacitor, :class:`~valve_model_pkg.model.ElectronicsConfig`).

Both are piecewise constant (zero-order hold): value ``k`` applies from ``t_s[k]`` to
``t_s[k + 1]``, and the first value also from t = 0 (every run starts at t = 0 with the
valve closed at rest, the coil de-energised and the capacitor empty). A PWM command is
latched at the next main PWM period start, as :class:`~valve_model_pkg.model.ValveStepper`
and the real valve do (the first period starts at t = 0 with the first command); a
command given exactly at a period start takes effect at that period start. A duty of 0
given within a period switches the coil off at once (docs/safety.md, "Close semantics"). A supply
voltage change acts at once.

Samples are either the instantaneous state at each sample time (``'instant'``) or the
mean over each sample interval (``'interval_mean'``: over ``[t_{k-1}, t_k]``, over
``[0, t_0]`` for the first sample), as a telemetry stream that reports the mean coil
current since its previous sample does. The means are exact integrals of the model
(accumulators integrated with the state, not averages of samples).

The integrator is the one of :mod:`valve_model_pkg.model.kernel` (fixed-step RK4 landing on
every scheduled edge, exact end-stop impacts); every function of this module uses it, so
identification, maps and the real-time stepper simulate the same model.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from . import kernel as _k
from .electronics import ElectronicsConfig
from .parameters import ParameterError, ValveParameters
from .simulation import DEFAULT_SUPPLY_PRESSURE_PA, _broadcast, _n_runs, _param_matrix

__all__ = ['InputTrace', 'TraceBatchResult', 'simulate_trace_batch', 'SAMPLING_MODES',
           'PARALLEL_MIN_BATCH']

#: Accepted values of ``sampling``.
SAMPLING_MODES = ('instant', 'interval_mean')

#: Batches smaller than this run on the calling thread: waking numba's thread pool for a
#: few runs costs more than it gains, badly so on a busy machine (measured: 12 ms instead
#: of 2 ms for one run with another process per core).
PARALLEL_MIN_BATCH = 8

_E_BARE = ElectronicsConfig.off().to_vector()


def _as_1d(name: str, value: float | np.ndarray, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(n, float(a))
    if a.shape != (n,):
        raise ParameterError(f'{name} must be a scalar or have shape ({n},), got {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ParameterError(f'{name} must be finite')
    return a


def _change_times(t_s: np.ndarray | Sequence[float]) -> np.ndarray:
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise ParameterError(f't_s must be a non-empty 1-D array, got shape {t.shape}')
    if not np.all(np.isfinite(t)) or t[0] < 0.0:
        raise ParameterError('t_s must be finite and start at t >= 0 s')
    if np.any(np.diff(t) <= 0.0):
        raise ParameterError('t_s must be strictly increasing')
    return t


@dataclasses.dataclass(frozen=True)
class InputTrace:
    """A piecewise-constant input of the valve (build it with the two classmethods).

    Attributes
    ----------
    kind : str
        ``'coil_voltage'`` (bare coil) or ``'pwm_commands'`` (through the electronics).
    t_s : numpy.ndarray, shape (n,)
        Times at which each value starts to apply, s (strictly increasing, >= 0; the
        first value also applies from t = 0).
    supply_voltage_v : numpy.ndarray, shape (n,)
        Coil terminal voltage (``coil_voltage``) or driver supply voltage
        (``pwm_commands``), V.
    duty : numpy.ndarray, shape (n,)
        Main PWM duty in [0, 1] (1 for a ``coil_voltage`` trace).
    pwm_frequency_hz : numpy.ndarray, shape (n,)
        Main PWM frequency, Hz (0 for a ``coil_voltage`` trace: no PWM).
    """

    kind: str
    t_s: np.ndarray
    supply_voltage_v: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray

    @classmethod
    def coil_voltage(cls, t_s: np.ndarray | Sequence[float],
                     v: np.ndarray | Sequence[float] | float) -> InputTrace:
        """Terminal voltage of the bare coil, zero-order hold.

        Parameters
        ----------
        t_s : array_like, shape (n,)
            Start time of each level, s.
        v : array_like, shape (n,) or float
            Coil terminal voltage from ``t_s[k]`` on, V (negative levels allowed: the
            bare coil has no reverse-blocking diode).

        Returns
        -------
        InputTrace
            Consecutive equal levels are merged (an edge costs a kernel event).
        """
        t = _change_times(t_s)
        volts = _as_1d('v', v, t.size)
        keep = np.ones(t.size, dtype=bool)
        keep[1:] = volts[1:] != volts[:-1]
        t, volts = t[keep], volts[keep]
        return cls('coil_voltage', t, volts, np.ones(t.size), np.zeros(t.size))

    @classmethod
    def pwm_commands(cls, t_s: np.ndarray | Sequence[float],
                     duty: np.ndarray | Sequence[float] | float,
                     pwm_frequency_hz: np.ndarray | Sequence[float] | float = 50.0,
                     supply_voltage_v: np.ndarray | Sequence[float] | float = 24.0
                     ) -> InputTrace:
        """Main PWM commands through the drive electronics, zero-order hold.

        Parameters
        ----------
        t_s : array_like, shape (n,)
            Time each command is given, s. Duty and frequency are latched at the next
            main PWM period start (the first period starts at t = 0 with command 0).
        duty : array_like, shape (n,) or float
            Main PWM duty cycle in [0, 1].
        pwm_frequency_hz : array_like, shape (n,) or float
            Main PWM frequency, Hz (> 0).
        supply_voltage_v : array_like, shape (n,) or float
            Driver supply voltage from ``t_s[k]`` on (acts at once), V.

        Returns
        -------
        InputTrace
        """
        t = _change_times(t_s)
        duty_a = _as_1d('duty', duty, t.size)
        freq = _as_1d('pwm_frequency_hz', pwm_frequency_hz, t.size)
        volts = _as_1d('supply_voltage_v', supply_voltage_v, t.size)
        if np.any((duty_a < 0.0) | (duty_a > 1.0)):
            raise ParameterError('duty must be in [0, 1]')
        if np.any(freq <= 0.0):
            raise ParameterError('pwm_frequency_hz must be positive')
        return cls('pwm_commands', t, volts, duty_a, freq)

    @property
    def period_s(self) -> np.ndarray:
        """Main PWM period of each value, s (inf for a coil-voltage trace)."""
        with np.errstate(divide='ignore'):
            return np.where(self.pwm_frequency_hz > 0.0, 1.0 / self.pwm_frequency_hz,
                            np.inf)


@dataclasses.dataclass(frozen=True)
class TraceBatchResult:
    """Sampled response of many runs to one :class:`InputTrace`.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n_samples,)
        Sample times, s.
    coil_current_a : numpy.ndarray, shape (n_runs, n_samples)
        Coil terminal current, A (eq. 5; with eddy currents the terminal, not the
        magnetising, current).
    coil_voltage_v : numpy.ndarray, shape (n_runs, n_samples)
        Coil terminal voltage, V.
    spool_position_m : numpy.ndarray, shape (n_runs, n_samples)
        Spool position x, m (0 closed, ``stroke_m`` open).
    spool_velocity_m_s : numpy.ndarray, shape (n_runs, n_samples)
        Spool velocity, m/s.
    coil_temperature_rise_k : numpy.ndarray, shape (n_runs, n_samples)
        Coil temperature above the reference (``coil_heating``), K; always instantaneous.
    mode : numpy.ndarray of int, shape (n_runs, n_samples)
        Mechanical mode at the sample time (``mechanics.MODE_*``); always instantaneous.
    sampling : str
        ``'instant'`` or ``'interval_mean'`` (current, voltage, position and velocity
        averaged over each sample interval).
    n_steps : numpy.ndarray of int, shape (n_runs,)
        RK4 steps taken per run (incl. redone event steps).
    """

    t_s: np.ndarray
    coil_current_a: np.ndarray
    coil_voltage_v: np.ndarray
    spool_position_m: np.ndarray
    spool_velocity_m_s: np.ndarray
    coil_temperature_rise_k: np.ndarray
    mode: np.ndarray
    sampling: str
    n_steps: np.ndarray


def _interval_means(t: np.ndarray, acc: np.ndarray, start: float,
                    instant: np.ndarray) -> np.ndarray:
    """Mean over each sample interval from an accumulated integral ``acc`` (runs x n)."""
    prev_t = np.concatenate(([0.0], t[:-1]))
    width = t - prev_t
    prev = np.concatenate((np.full((acc.shape[0], 1), start), acc[:, :-1]), axis=1)
    mean = instant.copy()
    ok = width > 0.0  # a first sample at t = 0 has no interval: its instantaneous value
    mean[:, ok] = (acc[:, ok] - prev[:, ok]) / width[ok]
    return mean


def simulate_trace_batch(params_list: ValveParameters | Sequence[ValveParameters]
                         | np.ndarray, trace: InputTrace,
                         sample_times_s: np.ndarray | Sequence[float], *,
                         electronics: ElectronicsConfig | None = None,
                         sampling: str = 'instant',
                         supply_pressure_pa: float | np.ndarray = DEFAULT_SUPPLY_PRESSURE_PA,
                         output_pressure_pa: float | np.ndarray = 0.0,
                         h_free_s: float = _k.DEFAULT_H_FREE_S,
                         h_stop_s: float = _k.DEFAULT_H_STOP_S, validate: bool = True,
                         parallel: bool = True) -> TraceBatchResult:
    """Simulate many parameter sets under one input trace (the model's general entry point).

    Each run integrates eqs. (1)-(11) of Taghizadeh et al. (2009) (inductance eq. 4,
    coil circuit eqs. 5-7, force eqs. 8-10, spool motion eq. 11, with the optional
    effects of :data:`~valve_model_pkg.model.EFFECTS`) from rest at t = 0.

    Parameters
    ----------
    params_list : ValveParameters, sequence of ValveParameters or numpy.ndarray
        One set, a list, or a matrix of shape (n_runs, len(PARAMETER_FIELDS)) in
        :data:`~valve_model_pkg.model.PARAMETER_FIELDS` order (``to_vector``).
    trace : InputTrace
        The input, from :meth:`InputTrace.coil_voltage` (bare coil) or
        :meth:`InputTrace.pwm_commands` (through the drive electronics).
    sample_times_s : array_like, shape (n_samples,)
        Strictly increasing sample times, s (>= 0, any spacing; the integrator lands on
        each one exactly).
    electronics : ElectronicsConfig, optional
        Drive electronics of a ``pwm_commands`` trace (default ``ElectronicsConfig()``).
        Refused for a ``coil_voltage`` trace, which drives the bare coil.
    sampling : {'instant', 'interval_mean'}
        Instantaneous values at each sample time, or means over each sample interval
        (``[t_{k-1}, t_k]``, ``[0, t_0]`` for the first; a first sample at t = 0 keeps its
        instantaneous value). Temperature and mode are always instantaneous.
    supply_pressure_pa, output_pressure_pa : float or numpy.ndarray
        Gauge pressures of eq. (10), Pa; scalars or per-run arrays of shape (n_runs,).
    h_free_s, h_stop_s : float
        Maximum RK4 step with the spool moving / resting on a stop, s.
    validate : bool
        Validate every row of a parameter matrix (about 20 us per row).
    parallel : bool
        Use numba's thread pool for batches of at least :data:`PARALLEL_MIN_BATCH` runs.
        False runs on the calling thread without the GIL, so several Python threads can
        simulate at once (numba's default threading layer must not be entered from two
        threads).

    Returns
    -------
    TraceBatchResult

    Raises
    ------
    ParameterError
        On invalid parameters, times, sampling mode or an electronics setting given with
        a coil-voltage trace.

    Examples
    --------
    >>> trace = InputTrace.pwm_commands([0.0, 0.1], duty=[0.3, 0.7])
    >>> t = np.arange(1, 201) * 1e-3                    # 1 kHz telemetry
    >>> res = simulate_trace_batch(load_parameters(), trace, t, sampling='interval_mean')
    >>> res.coil_current_a.shape
    (1, 200)
    """
    if not isinstance(trace, InputTrace):
        raise ParameterError(f'trace must be an InputTrace, got {type(trace).__name__}')
    if sampling not in SAMPLING_MODES:
        raise ParameterError(f'sampling must be one of {SAMPLING_MODES}, got {sampling!r}')
    if trace.kind == 'coil_voltage':
        if electronics is not None:
            raise ParameterError('a coil_voltage trace drives the bare coil: give no '
                                 'electronics (use InputTrace.pwm_commands for the drive)')
        e = _E_BARE
    else:
        e = (electronics if electronics is not None else ElectronicsConfig()).to_vector()
    t = np.asarray(sample_times_s, dtype=np.float64)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or t[0] < 0.0 \
            or np.any(np.diff(t) <= 0.0):
        raise ParameterError('sample_times_s must be a non-empty, finite, strictly '
                             'increasing 1-D array starting at t >= 0 s')
    for name, h in (('h_free_s', h_free_s), ('h_stop_s', h_stop_s)):
        if not np.isfinite(h) or h <= 0.0:
            raise ParameterError(f'{name} must be positive, got {h!r}')
    n_req = _n_runs(params_list, supply_pressure_pa, output_pressure_pa)
    mat = _param_matrix(params_list, n_req, validate)
    n = mat.shape[0]
    arr = _broadcast(n, supply_pressure_pa=supply_pressure_pa,
                     output_pressure_pa=output_pressure_pa)
    if np.any(arr['supply_pressure_pa'] < -1.0e5) or np.any(arr['output_pressure_pa'] < -1e5):
        raise ParameterError('pressures must be gauge pressures above -1 bar')
    out = np.zeros((n, t.size, _k.N_OUT))
    stats = np.zeros((n, 2))
    _k.trace_batch(mat, e, trace.t_s, trace.supply_voltage_v, trace.duty, trace.period_s,
                   arr['supply_pressure_pa'], arr['output_pressure_pa'], t, float(h_free_s),
                   float(h_stop_s), out, stats,
                   parallel=parallel and n >= PARALLEL_MIN_BATCH)
    cur = out[:, :, _k.O_I]
    volt = out[:, :, _k.O_V]
    pos = out[:, :, _k.O_X]
    vel = out[:, :, _k.O_XDOT]
    if sampling == 'interval_mean':
        cur = _interval_means(t, out[:, :, _k.O_QI], 0.0, cur)
        volt = _interval_means(t, out[:, :, _k.O_QV], 0.0, volt)
        mean_x = _interval_means(t, out[:, :, _k.O_QX], 0.0, pos)
        # the mean velocity over an interval is the change of position over it
        vel = _interval_means(t, pos, 0.0, vel)
        pos = mean_x
    return TraceBatchResult(
        t_s=t.copy(), coil_current_a=np.ascontiguousarray(cur),
        coil_voltage_v=np.ascontiguousarray(volt), spool_position_m=np.ascontiguousarray(pos),
        spool_velocity_m_s=np.ascontiguousarray(vel),
        coil_temperature_rise_k=np.ascontiguousarray(out[:, :, _k.O_DT]),
        mode=out[:, :, _k.O_MODE].astype(int), sampling=sampling,
        n_steps=stats[:, 0].astype(np.int64))
