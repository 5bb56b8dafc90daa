"""Offline simulations: voltage steps and PWM drive, single runs and parallel batches.

All runs start with the valve closed and at rest, the coil de-energised and the capacitor
empty. Pressures are gauge, Pa. The integration method is described in
:mod:`valve_model_pkg.model.kernel`.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from . import kernel as _k
from .averaging import hold_period_means, moving_average
from .electronics import ElectronicsConfig
from .mechanics import MODE_CLOSED, MODE_OPEN
from .orifice import orifice_mass_flow
from . import parameters as _param
from .parameters import PARAMETER_FIELDS, ParameterError, ValveParameters

__all__ = [
    'DEFAULT_SUPPLY_PRESSURE_PA',
    'SimulationResult',
    'StepMetrics',
    'StepBatchResult',
    'PwmBatchResult',
    'simulate_step',
    'simulate_pwm',
    'simulate_step_batch',
    'simulate_pwm_batch',
    'step_metrics',
    'closing_time',
]

#: Supply pressure assumed for the paper's Fig. 4/5 step tests, Pa gauge (4 bar: the
#: pressure of all the paper's stated experiments; Fig. 4 itself does not state one).
DEFAULT_SUPPLY_PRESSURE_PA = 4.0e5


@dataclasses.dataclass(frozen=True)
class SimulationResult:
    """Sampled trace of one simulation.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n,)
        Sample times, s.
    voltage_v : numpy.ndarray, shape (n,)
        Coil terminal voltage applied by the driver, V.
    current_a : numpy.ndarray, shape (n,)
        Coil terminal current, A.
    position_m : numpy.ndarray, shape (n,)
        Spool position, m (0 = closed, ``stroke_m`` = open).
    velocity_m_s : numpy.ndarray, shape (n,)
        Spool velocity, m/s.
    temperature_rise_k : numpy.ndarray, shape (n,)
        Coil temperature above the reference (coil_heating), K.
    mode : numpy.ndarray of int, shape (n,)
        Mechanical mode (mechanics.MODE_*: 0 moving, 1 closed stop, 2 open stop, 3 stuck).
    position_avg_m : numpy.ndarray, shape (n,)
        The suite's per-period moving average of the position (Section 5), m: the exact
        mean over the last complete main PWM period, 0 before the first one ends (see
        :mod:`~valve_model_pkg.model.averaging`). A step run has no PWM period: there, a
        trailing 20 ms window (:func:`~valve_model_pkg.model.moving_average`).
    period_end_s, period_avg_position_m : numpy.ndarray, shape (k,)
        Exact average position over each completed main PWM period (from the kernel).
    duty, pwm_frequency_hz, supply_voltage_v, supply_pressure_pa, output_pressure_pa : float
        Inputs of the run.
    experiment : str
        ``'step'`` or ``'pwm'``.
    params : ValveParameters
    electronics : ElectronicsConfig
    n_steps : int
        RK4 steps taken (incl. redone event steps).
    """

    t_s: np.ndarray
    voltage_v: np.ndarray
    current_a: np.ndarray
    position_m: np.ndarray
    velocity_m_s: np.ndarray
    temperature_rise_k: np.ndarray
    mode: np.ndarray
    position_avg_m: np.ndarray
    period_end_s: np.ndarray
    period_avg_position_m: np.ndarray
    duty: float
    pwm_frequency_hz: float
    supply_voltage_v: float
    supply_pressure_pa: float
    output_pressure_pa: float
    experiment: str
    params: ValveParameters
    electronics: ElectronicsConfig
    n_steps: int

    @property
    def mass_flow_kg_s(self) -> np.ndarray:
        """Mass flow from the moving-average position, eq. (12), kg/s."""
        return orifice_mass_flow(self.position_avg_m, self.supply_pressure_pa,
                                 self.output_pressure_pa, self.params)


@dataclasses.dataclass(frozen=True)
class StepMetrics:
    """Opening figures of a step response (Fig. 4 / Fig. 5).

    Attributes
    ----------
    motion_start_s : float
        First time the spool leaves the closed stop, s (nan if it never moves).
    stroke_end_s : float
        First time it reaches the open stop, s (nan if never).
    peak_current_a : float
        Local current peak during the motion (between start and stroke end), A.
    peak_time_s : float
        Time of that peak, s.
    final_current_a : float
        Current at the end of the trace, A.
    """

    motion_start_s: float
    stroke_end_s: float
    peak_current_a: float
    peak_time_s: float
    final_current_a: float


def _sample_count(duration_s: float, sample_rate_hz: float) -> tuple[int, float]:
    if not np.isfinite(duration_s) or duration_s <= 0.0:
        raise ParameterError(f'duration_s must be positive, got {duration_s!r}')
    if not np.isfinite(sample_rate_hz) or sample_rate_hz <= 0.0:
        raise ParameterError(f'sample_rate_hz must be positive, got {sample_rate_hz!r}')
    dt = 1.0 / sample_rate_hz
    return int(np.floor(duration_s * sample_rate_hz + 1e-9)) + 1, dt


def _check_pwm(duty: float, pwm_frequency_hz: float) -> None:
    if not np.isfinite(duty) or not 0.0 <= duty <= 1.0:
        raise ParameterError(f'duty must be in [0, 1], got {duty!r}')
    if not np.isfinite(pwm_frequency_hz) or pwm_frequency_hz <= 0.0:
        raise ParameterError(f'pwm_frequency_hz must be positive, got {pwm_frequency_hz!r}')


def _check_pressure(name: str, value: float) -> None:
    if not np.isfinite(value) or value < -1.0e5:
        raise ParameterError(f'{name} must be a finite gauge pressure above -1 bar, '
                             f'got {value!r}')


def _run(params: ValveParameters, electronics: ElectronicsConfig, supply_voltage_v: float,
         duty: float, period_s: float, first_edge_s: float, duration_s: float,
         supply_pressure_pa: float, output_pressure_pa: float, sample_rate_hz: float,
         h_free_s: float, h_stop_s: float, avg_window_s: float, experiment: str
         ) -> SimulationResult:
    if not np.isfinite(supply_voltage_v):
        raise ParameterError(f'voltage must be finite, got {supply_voltage_v!r}')
    _check_pressure('supply_pressure_pa', supply_pressure_pa)
    _check_pressure('output_pressure_pa', output_pressure_pa)
    for name, h in (('h_free_s', h_free_s), ('h_stop_s', h_stop_s)):
        if not np.isfinite(h) or h <= 0.0:
            raise ParameterError(f'{name} must be positive, got {h!r}')
    n, dt = _sample_count(duration_s, sample_rate_hz)
    p = _k.derive_parameters(params.to_vector())
    e = electronics.to_vector()
    d = _k.new_drive_state(supply_voltage_v, duty, period_s, first_edge_s, supply_pressure_pa,
                           output_pressure_pa, sample_dt_s=dt, first_sample_s=0.0)
    y = np.zeros(_k.N_Y)
    out = np.zeros((n, _k.N_OUT))
    n_per = int(duration_s / period_s) + 2 if np.isfinite(period_s) else 0
    avg = np.full(n_per, np.nan)
    _k.advance(p, e, y, d, (n - 1) * dt, h_free_s, h_stop_s, out, avg)
    t = np.arange(n) * dt
    n_done = min(int(d[_k.D_AVG_IDX]), n_per)
    ends = first_edge_s + period_s * np.arange(1, n_done + 1) if n_done else np.zeros(0)
    if experiment == 'pwm':
        # the suite's moving average (averaging.last_period_mean), from the kernel's exact
        # period means: what ValveStepper and the simulator node publish
        position_avg = hold_period_means(t, ends, avg[:n_done], period_s)
    else:
        # a step has no main PWM period: a trailing window (averaging.moving_average)
        position_avg = moving_average(t, out[:, _k.O_X], avg_window_s) if n > 1 \
            else out[:, _k.O_X].copy()
    return SimulationResult(
        t_s=t, voltage_v=out[:, _k.O_V].copy(), current_a=out[:, _k.O_I].copy(),
        position_m=out[:, _k.O_X].copy(), velocity_m_s=out[:, _k.O_XDOT].copy(),
        temperature_rise_k=out[:, _k.O_DT].copy(), mode=out[:, _k.O_MODE].astype(int),
        position_avg_m=position_avg,
        period_end_s=ends, period_avg_position_m=avg[:n_done].copy(),
        duty=float(duty), pwm_frequency_hz=float(1.0 / period_s) if experiment == 'pwm'
        else 0.0,
        supply_voltage_v=float(supply_voltage_v), supply_pressure_pa=float(supply_pressure_pa),
        output_pressure_pa=float(output_pressure_pa), experiment=experiment, params=params,
        electronics=electronics, n_steps=int(d[_k.D_N_STEPS]))


def simulate_step(params: ValveParameters, voltage_v: float = 24.0,
                  duration_s: float = 0.02,
                  supply_pressure_pa: float = DEFAULT_SUPPLY_PRESSURE_PA,
                  output_pressure_pa: float = 0.0, *, sample_rate_hz: float = 100e3,
                  step_time_s: float = 0.0, electronics: ElectronicsConfig | None = None,
                  h_free_s: float = _k.DEFAULT_H_FREE_S,
                  h_stop_s: float = _k.DEFAULT_H_STOP_S) -> SimulationResult:
    """Response to a voltage step on the bare coil (paper Figs. 4 and 5).

    Parameters
    ----------
    params : ValveParameters
    voltage_v : float
        Step voltage, V (24 V in Fig. 4, 15 V in Fig. 5).
    duration_s : float
        Simulated time, s.
    supply_pressure_pa, output_pressure_pa : float
        Gauge pressures for eq. (10), Pa (default 4 bar supply, see
        :data:`DEFAULT_SUPPLY_PRESSURE_PA`).
    sample_rate_hz : float
        Output sampling rate, Hz (samples at k / rate, exact, not interpolated).
    step_time_s : float
        Time at which the voltage is switched on, s (0 V before).
    electronics : ElectronicsConfig, optional
        Default :meth:`ElectronicsConfig.off` (bare coil, as on a bench).
    h_free_s, h_stop_s : float
        Maximum RK4 step with the spool moving / resting, s.

    Returns
    -------
    SimulationResult
    """
    if electronics is None:
        electronics = ElectronicsConfig.off()
    if not np.isfinite(step_time_s) or step_time_s < 0.0:
        raise ParameterError(f'step_time_s must be non-negative, got {step_time_s!r}')
    # a step is one main PWM period longer than the run with duty 1
    period = 2.0 * (duration_s + step_time_s) + 1.0 if np.isfinite(duration_s) else 1.0
    return _run(params, electronics, voltage_v, 1.0, period, step_time_s, duration_s,
                supply_pressure_pa, output_pressure_pa, sample_rate_hz, h_free_s, h_stop_s,
                0.02, 'step')


def simulate_pwm(params: ValveParameters, electronics: ElectronicsConfig | None = None,
                 duty: float = 0.4, pwm_frequency_hz: float = 50.0, duration_s: float = 0.1,
                 supply_pressure_pa: float = DEFAULT_SUPPLY_PRESSURE_PA,
                 output_pressure_pa: float = 0.0, *, supply_voltage_v: float = 24.0,
                 sample_rate_hz: float = 100e3, h_free_s: float = _k.DEFAULT_H_FREE_S,
                 h_stop_s: float = _k.DEFAULT_H_STOP_S) -> SimulationResult:
    """Response to a main PWM input through the drive electronics (paper Fig. 6).

    Parameters
    ----------
    params : ValveParameters
    electronics : ElectronicsConfig, optional
        Default ``ElectronicsConfig()`` (everything on).
    duty : float
        Main PWM duty cycle in [0, 1].
    pwm_frequency_hz : float
        Main PWM frequency, Hz; the first period starts (rising edge) at t = 0.
    duration_s : float
        Simulated time, s.
    supply_pressure_pa, output_pressure_pa : float
        Gauge pressures, Pa.
    supply_voltage_v : float
        Driver supply voltage, V.
    sample_rate_hz : float
        Output sampling rate, Hz.
    h_free_s, h_stop_s : float
        Maximum RK4 step with the spool moving / resting, s.

    Returns
    -------
    SimulationResult
        ``position_avg_m`` is the suite's moving average (the mean over the last
        complete period, held); the per-period means are in ``period_avg_position_m``.
    """
    if electronics is None:
        electronics = ElectronicsConfig()
    _check_pwm(duty, pwm_frequency_hz)
    period = 1.0 / pwm_frequency_hz
    return _run(params, electronics, supply_voltage_v, duty, period, 0.0, duration_s,
                supply_pressure_pa, output_pressure_pa, sample_rate_hz, h_free_s, h_stop_s,
                period, 'pwm')


def step_metrics(result: SimulationResult) -> StepMetrics:
    """Start of motion, end of stroke and the local current peak of a step response.

    The start of motion is the first sample at which the spool has left the closed stop
    (mechanical mode, exact to one sample); the stroke end is the first sample on the open
    stop; the peak is the largest current sample between the two.
    """
    t, i, mode = result.t_s, result.current_a, result.mode
    left = np.nonzero(mode != MODE_CLOSED)[0]
    if len(left) == 0:
        return StepMetrics(np.nan, np.nan, np.nan, np.nan, float(i[-1]))
    k0 = int(left[0])
    at_open = np.nonzero(mode[k0:] == MODE_OPEN)[0]
    if len(at_open) == 0:
        return StepMetrics(float(t[k0]), np.nan, np.nan, np.nan, float(i[-1]))
    k1 = k0 + int(at_open[0])
    kp = k0 + int(np.argmax(i[k0:k1 + 1]))
    return StepMetrics(float(t[k0]), float(t[k1]), float(i[kp]), float(t[kp]), float(i[-1]))


def closing_time(result: SimulationResult, falling_edge_s: float) -> float:
    """Time from a main PWM falling edge until the spool is back on the closed stop, s."""
    t, x = result.t_s, result.position_m
    after = np.nonzero((t >= falling_edge_s) & (x <= 0.0))[0]
    moved = np.nonzero((t >= falling_edge_s) & (x > 0.0))[0]
    if len(moved) == 0 or len(after) == 0:
        return np.nan
    closed = after[after > moved[0]]
    return float(t[closed[0]] - falling_edge_s) if len(closed) else np.nan


# --------------------------------------------------------------------------------------
# Batch API
# --------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StepBatchResult:
    """Voltage-step responses of many runs.

    Attributes
    ----------
    t_s : numpy.ndarray, shape (n_samples,)
    current_a : numpy.ndarray, shape (n_runs, n_samples)
    position_m : numpy.ndarray, shape (n_runs, n_samples)
    """

    t_s: np.ndarray
    current_a: np.ndarray
    position_m: np.ndarray


@dataclasses.dataclass(frozen=True)
class PwmBatchResult:
    """Period-averaged positions of many PWM runs.

    Attributes
    ----------
    position_avg_m : numpy.ndarray, shape (n_runs, n_periods)
        Average spool position over each main PWM period, m.
    duty, pwm_frequency_hz, supply_pressure_pa : numpy.ndarray, shape (n_runs,)
    """

    position_avg_m: np.ndarray
    duty: np.ndarray
    pwm_frequency_hz: np.ndarray
    supply_pressure_pa: np.ndarray

    @property
    def steady_position_m(self) -> np.ndarray:
        """Average position over the last simulated period, m, shape (n_runs,)."""
        return self.position_avg_m[:, -1]


def _param_matrix(params: ValveParameters | Sequence[ValveParameters] | np.ndarray,
                  n_hint: int, validate: bool) -> np.ndarray:
    if isinstance(params, ValveParameters):
        return np.tile(params.to_vector(), (max(n_hint, 1), 1))
    if isinstance(params, np.ndarray):
        mat = np.atleast_2d(np.asarray(params, dtype=np.float64))
        if mat.shape[1] != len(PARAMETER_FIELDS):
            raise ParameterError(f'parameter matrix must have {len(PARAMETER_FIELDS)} '
                                 f'columns (PARAMETER_FIELDS), got shape {mat.shape}')
        if validate and not _rows_valid(mat):
            # some row fails: the row-by-row check names the first one and its field
            for n, row in enumerate(mat):
                try:
                    ValveParameters.from_vector(row)
                except ParameterError as err:
                    raise ParameterError(f'parameter row {n}: {err}') from err
        return np.ascontiguousarray(mat)
    return np.array([p.to_vector() for p in params], dtype=np.float64)


def _rows_valid(mat: np.ndarray) -> bool:
    """True if every row passes ``ValveParameters.from_vector`` (whole-matrix test).

    The rules of ``parameters._validate``, column by column: about 1 ms for 1000 rows
    instead of about 20 ms (loaded machine: 130 ms) row by row, which was a tenth of a
    1000-run batch. It may only ever be stricter than the row-wise check (a False falls
    back to it); tests/unit/test_bank_model.py compares the two on random matrices.
    """
    col = {name: mat[:, k] for k, name in enumerate(PARAMETER_FIELDS)}
    with np.errstate(invalid='ignore'):
        ok = np.all(np.isfinite(mat))
        for name in _param._POSITIVE:
            ok = ok and bool(np.all(col[name] > 0.0))
        for name in _param._NON_NEGATIVE:
            ok = ok and bool(np.all(col[name] >= 0.0))
        ok = ok and bool(np.all(col['stroke_m'] < col['total_air_gap_m']))
        ok = ok and bool(np.all(col['discharge_coefficient'] <= 1.0))
        ok = ok and bool(np.all(col['heat_capacity_ratio'] > 1.0))
        for name in PARAMETER_FIELDS:
            lo, hi = _param._safe_range(name)
            ok = ok and bool(np.all((lo <= col[name]) & (col[name] <= hi)))
        ok = ok and bool(np.all(col['restitution_coefficient'] < 1.0))
    return ok


def _broadcast(n: int, **arrays: float | np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for name, value in arrays.items():
        a = np.asarray(value, dtype=np.float64)
        if a.ndim == 0:
            a = np.full(n, float(a))
        if a.shape != (n,):
            raise ParameterError(f'{name} must be a scalar or have shape ({n},), '
                                 f'got {a.shape}')
        if not np.all(np.isfinite(a)):
            raise ParameterError(f'{name} must be finite, got {a!r}')
        out[name] = np.ascontiguousarray(a)
    return out


def _n_runs(params: object, *arrays: float | np.ndarray) -> int:
    n = 1
    if not isinstance(params, ValveParameters):
        n = len(np.atleast_2d(params)) if isinstance(params, np.ndarray) else len(params)
    for a in arrays:
        a = np.asarray(a)
        if a.ndim > 0 and len(a) != 1:
            n = len(a) if n == 1 else n
    return n


def simulate_step_batch(params: ValveParameters | Sequence[ValveParameters] | np.ndarray,
                        voltage_v: float | np.ndarray = 24.0, duration_s: float = 0.01,
                        supply_pressure_pa: float | np.ndarray = DEFAULT_SUPPLY_PRESSURE_PA,
                        output_pressure_pa: float | np.ndarray = 0.0, *,
                        sample_rate_hz: float = 50e3, step_time_s: float = 0.0,
                        validate: bool = True, h_free_s: float = _k.DEFAULT_H_FREE_S,
                        h_stop_s: float = _k.DEFAULT_H_STOP_S) -> StepBatchResult:
    """Bare-coil voltage-step responses of many runs in parallel (numba ``prange``).

    For identification: each row of a parameter matrix is one run.

    Parameters
    ----------
    params : ValveParameters, sequence of ValveParameters or numpy.ndarray
        One set (shared by all runs), a list, or a matrix of shape (n_runs, n_fields) in
        :data:`PARAMETER_FIELDS` order (``ValveParameters.to_vector``).
    voltage_v, supply_pressure_pa, output_pressure_pa : float or numpy.ndarray
        Scalars or per-run arrays of shape (n_runs,).
    duration_s : float
        Simulated time per run, s.
    sample_rate_hz : float
        Output sampling rate, Hz.
    step_time_s : float
        Time the voltage switches on, s.
    validate : bool
        Validate every row of a parameter matrix (about 20 us per row).
    h_free_s, h_stop_s : float
        Maximum RK4 steps, s.

    Returns
    -------
    StepBatchResult
        ``current_a`` and ``position_m`` of shape (n_runs, n_samples).

    Notes
    -----
    Threads: numba's default (all cores); limit with ``numba.set_num_threads``.
    """
    n_req = _n_runs(params, voltage_v, supply_pressure_pa, output_pressure_pa)
    mat = _param_matrix(params, n_req, validate)
    n = mat.shape[0]
    arr = _broadcast(n, voltage_v=voltage_v, supply_pressure_pa=supply_pressure_pa,
                     output_pressure_pa=output_pressure_pa)
    n_s, dt = _sample_count(duration_s, sample_rate_hz)
    e = ElectronicsConfig.off().to_vector()
    cur, pos = _k.step_batch(mat, e, arr['voltage_v'], arr['supply_pressure_pa'],
                             arr['output_pressure_pa'], (n_s - 1) * dt, step_time_s, dt,
                             n_s, h_free_s, h_stop_s)
    return StepBatchResult(np.arange(n_s) * dt, cur, pos)


def simulate_pwm_batch(params: ValveParameters | Sequence[ValveParameters] | np.ndarray,
                       electronics: ElectronicsConfig | None = None,
                       duty: float | np.ndarray = 0.5,
                       pwm_frequency_hz: float | np.ndarray = 50.0,
                       supply_pressure_pa: float | np.ndarray = DEFAULT_SUPPLY_PRESSURE_PA,
                       output_pressure_pa: float | np.ndarray = 0.0, *, n_periods: int = 10,
                       supply_voltage_v: float | np.ndarray = 24.0, validate: bool = True,
                       h_free_s: float = _k.DEFAULT_H_FREE_S,
                       h_stop_s: float = _k.DEFAULT_H_STOP_S) -> PwmBatchResult:
    """Period-averaged spool positions of many PWM runs in parallel (Section 5 maps).

    Each run starts closed at rest with a rising edge at t = 0 and is simulated for
    ``n_periods`` main PWM periods.

    Parameters
    ----------
    params : ValveParameters, sequence or numpy.ndarray (n_runs, n_fields)
    electronics : ElectronicsConfig, optional
        Default ``ElectronicsConfig()``.
    duty, pwm_frequency_hz, supply_pressure_pa, output_pressure_pa, supply_voltage_v :
        Scalars or per-run arrays of shape (n_runs,).
    n_periods : int
        Periods per run.

    Returns
    -------
    PwmBatchResult
        ``position_avg_m`` of shape (n_runs, n_periods); ``steady_position_m`` is the last.
    """
    if electronics is None:
        electronics = ElectronicsConfig()
    if int(n_periods) < 1:
        raise ParameterError(f'n_periods must be at least 1, got {n_periods!r}')
    n_req = _n_runs(params, duty, pwm_frequency_hz, supply_pressure_pa, output_pressure_pa,
                    supply_voltage_v)
    mat = _param_matrix(params, n_req, validate)
    n = mat.shape[0]
    arr = _broadcast(n, duty=duty, pwm_frequency_hz=pwm_frequency_hz,
                     supply_pressure_pa=supply_pressure_pa,
                     output_pressure_pa=output_pressure_pa, supply_voltage_v=supply_voltage_v)
    if np.any((arr['duty'] < 0.0) | (arr['duty'] > 1.0)):
        raise ParameterError(f'duty must be in [0, 1], got {arr["duty"]!r}')
    if np.any(arr['pwm_frequency_hz'] <= 0.0):
        raise ParameterError(
            f'pwm_frequency_hz must be positive, got {arr["pwm_frequency_hz"]!r}')
    avg = _k.pwm_batch(mat, electronics.to_vector(), arr['supply_voltage_v'], arr['duty'],
                       1.0 / arr['pwm_frequency_hz'], arr['supply_pressure_pa'],
                       arr['output_pressure_pa'], int(n_periods), h_free_s, h_stop_s)
    return PwmBatchResult(avg, arr['duty'], arr['pwm_frequency_hz'],
                          arr['supply_pressure_pa'])
