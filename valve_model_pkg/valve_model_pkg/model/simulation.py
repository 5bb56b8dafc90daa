"""The model's one simulation entry, :func:`simulate_trace_batch`, and its short forms.

:func:`simulate_trace_batch` simulates many parameter sets (one run each) under an
:class:`~valve_model_pkg.model.InputTrace` and returns a
:class:`~valve_model_pkg.model.SimulationResult`. :func:`simulate_step` and
:func:`simulate_pwm` are the paper's experiments (Figs. 4-6) as one run of it.

Every run starts at t = 0 with the valve closed and at rest, the coil de-energised and the
capacitor empty. Pressures are gauge, Pa. Samples are the instantaneous state at each
sample time (``'instant'``) or the mean over each sample interval (``'interval_mean'``:
over ``[t_{k-1}, t_k]``, over ``[0, t_0]`` for the first sample), as a telemetry stream
that reports the mean coil current since its previous sample does; the means are exact
integrals of the model (accumulators integrated with the state).

The integrator is the one of :mod:`valve_model_pkg.model.kernel` (fixed-step RK4 landing on
every scheduled edge, exact end-stop impacts), so identification, maps and the real-time
stepper simulate the same model. This module calls two of its entries and both give the
same samples bit for bit where both apply:

* ``trace_batch`` (runs in parallel, any input from t = 0, any sample times), the default;
* ``advance`` run by run (the streaming integrator), when the period means are asked for
  (``n_periods``: the kernel integrates them at each period start) or a step starts after
  t = 0 (its edge lands exactly on the step time); it needs a constant input per run and
  sample times on a uniform grid ``t_0 + k dt`` (or none).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from . import kernel as _k
from . import parameters as _param
from .electronics import ElectronicsConfig
from .parameters import PARAMETER_FIELDS, ParameterError, ValveParameters
from .result import SimulationResult
from .trace import InputTrace

__all__ = [
    'DEFAULT_SUPPLY_PRESSURE_PA',
    'PARALLEL_MIN_BATCH',
    'SAMPLING_MODES',
    'simulate_pwm',
    'simulate_step',
    'simulate_trace_batch',
]

#: Supply pressure assumed for the paper's Fig. 4/5 step tests, Pa gauge (4 bar: the
#: pressure of all the paper's stated experiments; Fig. 4 itself does not state one).
DEFAULT_SUPPLY_PRESSURE_PA = 4.0e5

#: Accepted values of ``sampling``.
SAMPLING_MODES = ('instant', 'interval_mean')

#: Batches smaller than this run on the calling thread: waking numba's thread pool for a
#: few runs costs more than it gains, badly so on a busy machine (measured: 12 ms instead
#: of 2 ms for one run with another process per core).
PARALLEL_MIN_BATCH = 8

_E_BARE = ElectronicsConfig.off()

#: Sample times this close to a uniform grid are that grid (the kernel's event tolerance).
_GRID_TOLERANCE_S = 1e-12


# --------------------------------------------------------------------------------------
# Batch inputs: parameter matrix, per-run values
# --------------------------------------------------------------------------------------
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
    instead of about 20 ms row by row. It may only ever be stricter than the row-wise
    check (a False falls back to it); tests/unit/test_bank_model.py compares the two on
    random matrices.
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


def _n_runs(params: object, traces: object, *arrays: float | np.ndarray) -> int:
    n = 1
    if not isinstance(params, ValveParameters):
        n = len(np.atleast_2d(params)) if isinstance(params, np.ndarray) else len(params)
    if isinstance(traces, (list, tuple)) and n == 1:
        n = len(traces)
    for a in arrays:
        a = np.asarray(a)
        if a.ndim > 0 and len(a) != 1:
            n = len(a) if n == 1 else n
    return n


@dataclasses.dataclass(frozen=True)
class _Runs:
    """A checked request: what every kernel route needs."""

    matrix: np.ndarray                 # (n_runs, len(PARAMETER_FIELDS))
    traces: list[InputTrace]           # one per run
    electronics: ElectronicsConfig
    supply_pressure_pa: np.ndarray     # (n_runs,)
    output_pressure_pa: np.ndarray     # (n_runs,)
    t_s: np.ndarray                    # (n_samples,), empty for no samples
    h_free_s: float
    h_stop_s: float


@dataclasses.dataclass(frozen=True)
class _KernelRuns:
    """Raw kernel output of a batch."""

    out: np.ndarray                    # (n_runs, n_samples, N_OUT), columns O_*
    stats: np.ndarray                  # (n_runs, 2): steps, forced steps
    period_end_s: np.ndarray | None    # (n_runs, n_periods), NaN after a run's last
    period_avg_position_m: np.ndarray | None


def _check_traces(trace: InputTrace | Sequence[InputTrace], n: int) -> list[InputTrace]:
    if isinstance(trace, InputTrace):
        return [trace] * n
    if not isinstance(trace, (list, tuple)) or not trace \
            or not all(isinstance(tr, InputTrace) for tr in trace):
        raise ParameterError('trace must be an InputTrace or a non-empty list of them, got '
                             f'{type(trace).__name__}')
    traces = list(trace)
    if len(traces) != n:
        raise ParameterError(f'{len(traces)} traces given for {n} runs: give one trace or '
                             'one per run')
    if len({tr.kind for tr in traces}) != 1:
        raise ParameterError('the traces of one batch must be of one kind, got '
                             f'{sorted({tr.kind for tr in traces})}')
    if len({tr.has_pressures for tr in traces}) != 1:
        raise ParameterError('the traces of one batch must all carry pressures or none')
    return traces


def _electronics_for(kind: str, electronics: ElectronicsConfig | None) -> ElectronicsConfig:
    if kind == 'coil_voltage':
        if electronics is not None:
            raise ParameterError('a coil_voltage trace drives the bare coil: give no '
                                 'electronics (use InputTrace.pwm_commands for the drive)')
        return _E_BARE
    if kind == 'step':
        return electronics if electronics is not None else _E_BARE
    return electronics if electronics is not None else ElectronicsConfig()


def _check_times(sample_times_s: np.ndarray | Sequence[float] | None) -> np.ndarray:
    if sample_times_s is None:
        return np.zeros(0)
    t = np.asarray(sample_times_s, dtype=np.float64)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or t[0] < 0.0 \
            or np.any(np.diff(t) <= 0.0):
        raise ParameterError('sample_times_s must be a non-empty, finite, strictly '
                             'increasing 1-D array starting at t >= 0 s')
    return t


# --------------------------------------------------------------------------------------
# Kernel routes
# --------------------------------------------------------------------------------------
def _run_traces(runs: _Runs, parallel: bool) -> _KernelRuns:
    """``kernel.trace_batch``: the runs sharing a trace in one (parallel) call."""
    n, n_s = runs.matrix.shape[0], runs.t_s.size
    out = np.zeros((n, n_s, _k.N_OUT))
    stats = np.zeros((n, 2))
    groups: dict[tuple, list[int]] = {}
    for r, tr in enumerate(runs.traces):
        groups.setdefault(tr.key(), []).append(r)
    e = runs.electronics.to_vector()
    for idx in groups.values():
        tr = runs.traces[idx[0]]
        whole = len(idx) == n
        o = out if whole else np.zeros((len(idx), n_s, _k.N_OUT))
        s = stats if whole else np.zeros((len(idx), 2))
        sel = slice(None) if whole else np.array(idx)
        _k.trace_batch(runs.matrix[sel], e, tr.t_s, tr.supply_voltage_v, tr.duty,
                       tr.period_s, runs.supply_pressure_pa[sel],
                       runs.output_pressure_pa[sel], runs.t_s, runs.h_free_s,
                       runs.h_stop_s, o, s, parallel=parallel and len(idx) >= PARALLEL_MIN_BATCH,
                       seg_psup=tr.supply_pressure_pa, seg_pout=tr.output_pressure_pa)
        if not whole:
            out[sel], stats[sel] = o, s
    return _KernelRuns(out, stats, None, None)


def _uniform_grid(t: np.ndarray) -> tuple[float, float]:
    """(first sample, spacing) of sample times ``t_0 + k dt``, as the kernel records them.

    A grid within the kernel's event tolerance (1 ps) of such times counts (``k / rate``
    and ``k * (1 / rate)`` differ in the last bits); the kernel samples at ``t_0 + k dt``.
    """
    if t.size == 1:
        return float(t[0]), 1.0
    k = np.arange(t.size)
    t0, dt = float(t[0]), float(t[1] - t[0])
    if np.array_equal(t, t0 + k * dt):
        return t0, dt
    dt = float(t[-1] - t0) / (t.size - 1)
    if np.max(np.abs(t - (t0 + k * dt))) <= _GRID_TOLERANCE_S:
        return t0, dt
    raise ParameterError('period means (n_periods) and a step after t = 0 need sample '
                         'times on a uniform grid t_0 + k dt')


def _run_streaming(runs: _Runs, n_periods: int) -> _KernelRuns:
    """``kernel.advance`` run by run: exact period means and step edges at any time."""
    n, n_s = runs.matrix.shape[0], runs.t_s.size
    t0, dt = _uniform_grid(runs.t_s) if n_s else (0.0, math.inf)
    e = runs.electronics.to_vector()
    out = np.zeros((n, n_s, _k.N_OUT))
    stats = np.zeros((n, 2))
    ends = np.full((n, n_periods), np.nan)
    means = np.full((n, n_periods), np.nan)
    for r, tr in enumerate(runs.traces):
        if not tr.is_constant:
            raise ParameterError('period means (n_periods) and a step after t = 0 need a '
                                 'constant input per run (one trace value)')
        step = tr.kind == 'step'
        first_edge, period = (float(tr.t_s[0]), math.inf) if step else (0.0, tr.period_s[0])
        d = _k.new_drive_state(tr.supply_voltage_v[0], tr.duty[0], period, first_edge,
                               runs.supply_pressure_pa[r], runs.output_pressure_pa[r],
                               sample_dt_s=dt, first_sample_s=t0)
        avg = np.full(n_periods, np.nan)
        # without samples the run ends just past its last period's closing boundary
        t_end = runs.t_s[-1] if n_s else n_periods * period + 1e-9
        _k.advance(_k.derive_parameters(runs.matrix[r]), e, np.zeros(_k.N_Y), d, t_end,
                   runs.h_free_s, runs.h_stop_s, out[r], avg)
        n_done = min(int(d[_k.D_AVG_IDX]), n_periods)
        ends[r, :n_done] = first_edge + period * np.arange(1, n_done + 1)
        means[r, :n_done] = avg[:n_done]
        stats[r] = d[_k.D_N_STEPS], d[_k.D_N_FORCED]
    width = int(np.max(np.sum(np.isfinite(ends), axis=1), initial=0))
    return _KernelRuns(out, stats, ends[:, :width], means[:, :width])


def _interval_means(t: np.ndarray, acc: np.ndarray, instant: np.ndarray) -> np.ndarray:
    """Mean over each sample interval from an accumulated integral ``acc`` (runs x n)."""
    prev_t = np.concatenate(([0.0], t[:-1]))
    width = t - prev_t
    prev = np.concatenate((np.zeros((acc.shape[0], 1)), acc[:, :-1]), axis=1)
    mean = instant.copy()
    ok = width > 0.0  # a first sample at t = 0 has no interval: its instantaneous value
    mean[:, ok] = (acc[:, ok] - prev[:, ok]) / width[ok]
    return mean


def _samples(t: np.ndarray, out: np.ndarray, sampling: str) -> dict[str, np.ndarray]:
    """The per-sample fields of the result from the kernel's sample rows."""
    cur = out[:, :, _k.O_I]
    volt = out[:, :, _k.O_V]
    pos = out[:, :, _k.O_X]
    vel = out[:, :, _k.O_XDOT]
    if sampling == 'interval_mean' and t.size:
        cur = _interval_means(t, out[:, :, _k.O_QI], cur)
        volt = _interval_means(t, out[:, :, _k.O_QV], volt)
        mean_x = _interval_means(t, out[:, :, _k.O_QX], pos)
        # the mean velocity over an interval is the change of position over it
        vel = _interval_means(t, pos, vel)
        pos = mean_x
    return {'coil_current_a': np.ascontiguousarray(cur),
            'coil_voltage_v': np.ascontiguousarray(volt),
            'spool_position_m': np.ascontiguousarray(pos),
            'spool_velocity_m_s': np.ascontiguousarray(vel),
            'coil_temperature_rise_k': np.ascontiguousarray(out[:, :, _k.O_DT]),
            'mode': out[:, :, _k.O_MODE].astype(int)}


# --------------------------------------------------------------------------------------
# The entry
# --------------------------------------------------------------------------------------
def simulate_trace_batch(params_list: ValveParameters | Sequence[ValveParameters]
                         | np.ndarray, trace: InputTrace | Sequence[InputTrace],
                         sample_times_s: np.ndarray | Sequence[float] | None = None, *,
                         electronics: ElectronicsConfig | None = None,
                         sampling: str = 'instant', n_periods: int | None = None,
                         supply_pressure_pa: float | np.ndarray | None = None,
                         output_pressure_pa: float | np.ndarray | None = None,
                         h_free_s: float = _k.DEFAULT_H_FREE_S,
                         h_stop_s: float = _k.DEFAULT_H_STOP_S, validate: bool = True,
                         parallel: bool = True) -> SimulationResult:
    """Simulate many parameter sets under an input trace (the model's one entry point).

    Each run integrates eqs. (1)-(11) of Taghizadeh et al. (2009) (inductance eq. 4,
    coil circuit eqs. 5-7, force eqs. 8-10, spool motion eq. 11, with the optional
    effects of :data:`~valve_model_pkg.model.EFFECTS`) from rest at t = 0.

    Parameters
    ----------
    params_list : ValveParameters, sequence of ValveParameters or numpy.ndarray
        One set (shared by all runs), a list, or a matrix of shape
        (n_runs, len(PARAMETER_FIELDS)) in :data:`~valve_model_pkg.model.PARAMETER_FIELDS`
        order (``to_vector``).
    trace : InputTrace or sequence of InputTrace
        The input, shared by all runs or one per run (all of one kind):
        :meth:`InputTrace.coil_voltage` (bare coil), :meth:`InputTrace.pwm_commands`
        (through the drive electronics) or :meth:`InputTrace.step`.
    sample_times_s : array_like, shape (n_samples,), optional
        Strictly increasing sample times, s (>= 0, any spacing; the integrator lands on
        each one exactly). None: no samples (then ``n_periods`` sets the run length).
    electronics : ElectronicsConfig, optional
        Drive electronics of a ``pwm_commands`` trace (default ``ElectronicsConfig()``) or
        of a step (default: none, the bare coil). Refused for a ``coil_voltage`` trace.
    sampling : {'instant', 'interval_mean'}
        Instantaneous values at each sample time, or means over each sample interval
        (``[t_{k-1}, t_k]``, ``[0, t_0]`` for the first; a first sample at t = 0 keeps its
        instantaneous value). Temperature and mode are always instantaneous.
    n_periods : int, optional
        Also report the exact mean spool position over each main PWM period, at most
        ``n_periods`` of them (a constant ``pwm_commands`` value per run; the runs then go
        one after another). With sample times the runs end at the last sample; without,
        each lasts exactly ``n_periods`` periods (the static maps' runs).
    supply_pressure_pa, output_pressure_pa : float or numpy.ndarray, optional
        Constant gauge pressures of eq. (10), Pa; scalars or per-run arrays of shape
        (n_runs,). Default :data:`DEFAULT_SUPPLY_PRESSURE_PA` and 0. Not with traces that
        carry their own pressure course (``InputTrace`` ``supply_pressure_pa``), whose
        values act from their times on (the result's pressures are those at t = 0).
    h_free_s, h_stop_s : float
        Maximum RK4 step with the spool moving / resting on a stop, s.
    validate : bool
        Validate every row of a parameter matrix (about 1 us per row).
    parallel : bool
        Use numba's thread pool for runs sharing a trace, at least
        :data:`PARALLEL_MIN_BATCH` of them. False runs on the calling thread without the
        GIL, so several Python threads can simulate at once (numba's default threading
        layer must not be entered from two threads).

    Returns
    -------
    SimulationResult
        With a leading run axis (``result.run(r)`` is one run).

    Raises
    ------
    ParameterError
        On invalid parameters, traces, times, sampling mode, period request or an
        electronics setting given with a coil-voltage trace.

    Examples
    --------
    >>> trace = InputTrace.pwm_commands([0.0, 0.1], duty=[0.3, 0.7])
    >>> t = np.arange(1, 201) * 1e-3                    # 1 kHz telemetry
    >>> res = simulate_trace_batch(load_parameters(), trace, t, sampling='interval_mean')
    >>> res.coil_current_a.shape
    (1, 200)
    """
    if sampling not in SAMPLING_MODES:
        raise ParameterError(f'sampling must be one of {SAMPLING_MODES}, got {sampling!r}')
    n_req = _n_runs(params_list, trace, supply_pressure_pa, output_pressure_pa)
    traces = _check_traces(trace, n_req)
    supply_pressure_pa, output_pressure_pa = _constant_pressures(
        traces, supply_pressure_pa, output_pressure_pa)
    runs = _check_request(params_list, traces, n_req, sample_times_s, electronics,
                          supply_pressure_pa, output_pressure_pa, h_free_s, h_stop_s,
                          validate)
    late_step = any(tr.kind == 'step' and tr.t_s[0] > 0.0 for tr in traces)
    if n_periods is not None:
        if int(n_periods) < 1:
            raise ParameterError(f'n_periods must be at least 1, got {n_periods!r}')
        if traces[0].kind != 'pwm_commands':
            raise ParameterError('period means (n_periods) need main PWM commands')
        raw = _run_streaming(runs, int(n_periods))
    elif not runs.t_s.size:
        raise ParameterError('give sample_times_s, or n_periods for period means only')
    elif late_step:
        raw = _run_streaming(runs, 0)
        raw = dataclasses.replace(raw, period_end_s=None, period_avg_position_m=None)
    else:
        raw = _run_traces(runs, parallel)
    if isinstance(params_list, np.ndarray):
        params = runs.matrix
    else:
        params = (params_list,) * runs.matrix.shape[0] \
            if isinstance(params_list, ValveParameters) else tuple(params_list)
    return SimulationResult(
        t_s=runs.t_s.copy(), **_samples(runs.t_s, raw.out, sampling),
        period_end_s=raw.period_end_s, period_avg_position_m=raw.period_avg_position_m,
        sampling=sampling, n_steps=raw.stats[:, 0].astype(np.int64),
        n_forced_steps=raw.stats[:, 1].astype(np.int64),
        trace=trace if isinstance(trace, InputTrace) else tuple(traces),
        electronics=runs.electronics, params=params,
        supply_pressure_pa=runs.supply_pressure_pa,
        output_pressure_pa=runs.output_pressure_pa)


def _constant_pressures(traces: list[InputTrace], supply_pressure_pa: float | np.ndarray
                        | None, output_pressure_pa: float | np.ndarray | None
                        ) -> tuple[float | np.ndarray, float | np.ndarray]:
    """The runs' pressures at t = 0: the given constants, or the traces' first values."""
    if not traces[0].has_pressures:
        return (DEFAULT_SUPPLY_PRESSURE_PA if supply_pressure_pa is None
                else supply_pressure_pa, 0.0 if output_pressure_pa is None
                else output_pressure_pa)
    if supply_pressure_pa is not None or output_pressure_pa is not None:
        raise ParameterError('the traces carry the pressures: give no supply_pressure_pa '
                             'or output_pressure_pa')
    return (np.array([tr.supply_pressure_pa[0] for tr in traces]),
            np.array([tr.output_pressure_pa[0] for tr in traces]))


def _check_request(params_list: ValveParameters | Sequence[ValveParameters] | np.ndarray,
                   traces: list[InputTrace], n_req: int,
                   sample_times_s: np.ndarray | Sequence[float] | None,
                   electronics: ElectronicsConfig | None,
                   supply_pressure_pa: float | np.ndarray,
                   output_pressure_pa: float | np.ndarray, h_free_s: float,
                   h_stop_s: float, validate: bool) -> _Runs:
    """Check and normalise the inputs of :func:`simulate_trace_batch`."""
    e = _electronics_for(traces[0].kind, electronics)
    t = _check_times(sample_times_s)
    for name, h in (('h_free_s', h_free_s), ('h_stop_s', h_stop_s)):
        if not np.isfinite(h) or h <= 0.0:
            raise ParameterError(f'{name} must be positive, got {h!r}')
    mat = _param_matrix(params_list, n_req, validate)
    n = mat.shape[0]
    if len(traces) != n:
        raise ParameterError(f'{len(traces)} traces given for {n} parameter sets')
    arr = _broadcast(n, supply_pressure_pa=supply_pressure_pa,
                     output_pressure_pa=output_pressure_pa)
    if np.any(arr['supply_pressure_pa'] < -1.0e5) or np.any(arr['output_pressure_pa'] < -1e5):
        raise ParameterError('pressures must be gauge pressures above -1 bar')
    return _Runs(mat, traces, e, arr['supply_pressure_pa'], arr['output_pressure_pa'], t,
                 float(h_free_s), float(h_stop_s))


# --------------------------------------------------------------------------------------
# The paper's experiments as one run
# --------------------------------------------------------------------------------------
def _sample_times(duration_s: float, sample_rate_hz: float) -> np.ndarray:
    """Samples at k / rate from 0 to ``duration_s`` (a grid the kernel lands on)."""
    if not np.isfinite(duration_s) or duration_s <= 0.0:
        raise ParameterError(f'duration_s must be positive, got {duration_s!r}')
    if not np.isfinite(sample_rate_hz) or sample_rate_hz <= 0.0:
        raise ParameterError(f'sample_rate_hz must be positive, got {sample_rate_hz!r}')
    n = int(np.floor(duration_s * sample_rate_hz + 1e-9)) + 1
    return np.arange(n) * (1.0 / sample_rate_hz)


def _check_pressure(name: str, value: float) -> None:
    if not np.isfinite(value) or value < -1.0e5:
        raise ParameterError(f'{name} must be a finite gauge pressure above -1 bar, '
                             f'got {value!r}')


def simulate_step(params: ValveParameters, voltage_v: float = 24.0,
                  duration_s: float = 0.02,
                  supply_pressure_pa: float = DEFAULT_SUPPLY_PRESSURE_PA,
                  output_pressure_pa: float = 0.0, *, sample_rate_hz: float = 100e3,
                  step_time_s: float = 0.0, electronics: ElectronicsConfig | None = None,
                  h_free_s: float = _k.DEFAULT_H_FREE_S,
                  h_stop_s: float = _k.DEFAULT_H_STOP_S) -> SimulationResult:
    """Response to a voltage step on the bare coil (paper Figs. 4 and 5).

    One run of :func:`simulate_trace_batch` under ``InputTrace.step(voltage_v,
    step_time_s)``, sampled at k / ``sample_rate_hz``.

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
        One run (no run axis); ``position_avg_m`` is a trailing 20 ms window.
    """
    trace = InputTrace.step(voltage_v, step_time_s)
    _check_pressure('supply_pressure_pa', supply_pressure_pa)
    _check_pressure('output_pressure_pa', output_pressure_pa)
    t = _sample_times(duration_s, sample_rate_hz)
    return simulate_trace_batch(
        params, trace, t, electronics=electronics, supply_pressure_pa=supply_pressure_pa,
        output_pressure_pa=output_pressure_pa, h_free_s=h_free_s, h_stop_s=h_stop_s).run(0)


def simulate_pwm(params: ValveParameters, electronics: ElectronicsConfig | None = None,
                 duty: float = 0.4, pwm_frequency_hz: float = 50.0, duration_s: float = 0.1,
                 supply_pressure_pa: float = DEFAULT_SUPPLY_PRESSURE_PA,
                 output_pressure_pa: float = 0.0, *, supply_voltage_v: float = 24.0,
                 sample_rate_hz: float = 100e3, h_free_s: float = _k.DEFAULT_H_FREE_S,
                 h_stop_s: float = _k.DEFAULT_H_STOP_S) -> SimulationResult:
    """Response to a main PWM input through the drive electronics (paper Fig. 6).

    One run of :func:`simulate_trace_batch` under a constant
    ``InputTrace.pwm_commands``, sampled at k / ``sample_rate_hz``, with its period means.

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
        One run (no run axis). ``period_avg_position_m`` holds the mean of every
        completed period; ``position_avg_m`` is the suite's moving average (the mean over
        the last complete period, held).
    """
    if not np.isfinite(duty) or not 0.0 <= duty <= 1.0:
        raise ParameterError(f'duty must be in [0, 1], got {duty!r}')
    if not np.isfinite(pwm_frequency_hz) or pwm_frequency_hz <= 0.0:
        raise ParameterError(f'pwm_frequency_hz must be positive, got {pwm_frequency_hz!r}')
    if not np.isfinite(supply_voltage_v):
        raise ParameterError(f'voltage must be finite, got {supply_voltage_v!r}')
    _check_pressure('supply_pressure_pa', supply_pressure_pa)
    _check_pressure('output_pressure_pa', output_pressure_pa)
    t = _sample_times(duration_s, sample_rate_hz)
    trace = InputTrace.pwm_commands([0.0], duty, pwm_frequency_hz, supply_voltage_v)
    # room for every period the run completes
    n_periods = int(duration_s * pwm_frequency_hz) + 2
    return simulate_trace_batch(
        params, trace, t, electronics=electronics, n_periods=n_periods,
        supply_pressure_pa=supply_pressure_pa, output_pressure_pa=output_pressure_pa,
        h_free_s=h_free_s, h_stop_s=h_stop_s).run(0)
