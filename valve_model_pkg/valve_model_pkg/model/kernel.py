"""The valve model's integrator: its layouts and entry points, without numba.

The integrator (method, step policy, events: model/kernel_jit.py) works on float64
arrays: ``p`` derived parameters (``P_*``, :func:`derive_parameters`), ``e`` the
electronics (``ElectronicsConfig.to_vector()``), ``y`` the continuous state (``Y_*``),
``d`` the discrete drive and mode state (``D_*``, :func:`new_drive_state`), sample rows
``O_*`` and, for banks, ``S_*`` and ``IV_*``. The entry points below run the compiled
code of :func:`valve_model_pkg.model.aot.backend`: the ahead-of-time module when it is
built for the current kernel (no numba in the process), else the numba jit of
kernel_jit.py; the numbers are the same bit for bit (tests/unit/test_aot_kernel.py).

Batches (:func:`step_batch`, :func:`pwm_batch`, :func:`trace_batch`) spread their runs
over :func:`batch_threads` threads; the compiled row loops release the GIL, so the
threads run in parallel.

This module is internal to ``model/``: the rest of the suite uses the public entry points
(:func:`~valve_model_pkg.model.simulate_trace_batch` and friends), so the layouts may
change with the kernel.
"""
from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..errors import KernelInputError
from .aot import backend as _backend

if TYPE_CHECKING:
    from concurrent.futures import ThreadPoolExecutor

__all__ = [
    'DEFAULT_H_FREE_S', 'DEFAULT_H_STOP_S', 'N_OUT', 'N_Y', 'N_D', 'N_S',
    'derive_parameters', 'new_drive_state', 'advance', 'command', 'step_batch',
    'pwm_batch', 'trace_batch', 'bank_advance', 'bank_sample', 'batch_threads',
    'MIN_PERIOD_S', 'check_trace_rows',
]

#: Default RK4 step while the spool moves, s.
DEFAULT_H_FREE_S = 1.0e-5
#: Default RK4 step while the spool rests on a stop, s.
DEFAULT_H_STOP_S = 1.0e-4

# Derived parameter vector.
P_M = 0
P_K = 1
P_KL = 2       # N^2 A_e mu_c, eq. (4) numerator
P_L0 = 3       # l_c + 2 mu_r x_t
P_B2 = 4       # 2 mu_r
P_R = 5
P_XMAX = 6
P_DELTA = 7
P_B = 8
P_A1 = 9
P_A2 = 10
P_A3 = 11
P_A4 = 12
P_BETA = 13
P_GE = 14
P_FC = 15
P_RTH = 16
P_TAUTH = 17
P_LLEAK = 18
P_E = 19
P_LAMS = 20    # emulator form saturation_tanh: lambda_s, Wb (0 = off)
P_LADR = 21    # emulator form eddy_ladder: r = L_slow / L_fast (0 = off)
P_LADRB = 22   # eddy_ladder: R_b, ohm
P_EMU = 23     # 1.0 if an emulator form is on (selects the extended code path)
N_P = 24

# Continuous state.
Y_I = 0
Y_X = 1
Y_V = 2
Y_DT = 3
Y_Q = 4
N_Y = 5

# Drive phases (what the driver applies to the coil).
PH_OFF = 0        # main PWM low: capacitor pulse or 0 V
PH_SUPPLY = 1     # supply voltage (bare coil high phase, boost, chopper on)
PH_FREEWHEEL = 2  # chopper off, or the current has reached zero: 0 V
PH_CLAMP = 3      # -d[D_VNEG] (Zener, free-wheel diode) until the current reaches zero
PH_FAST = 4       # fast decay: -d[D_VS] until the current reaches zero (if blocked)

# Discrete state.
D_T = 0
D_MODE = 1
D_PHASE = 2
D_VS = 3
D_PSUP = 4
D_POUT = 5
D_DUTY = 6
D_PERIOD = 7
D_PEND_DUTY = 8
D_PEND_PERIOD = 9
D_NEXT_BOUNDARY = 10
D_NEXT_FALL = 11
D_NEXT_TICK = 12
D_CHOP_OFF = 13
D_MAIN_ON = 14
D_BOOST = 15
D_T_ON = 16
D_T_OFF = 17
D_VC_ON = 18
D_VC_OFF = 19
D_IMAX = 20
D_DIPPED = 21
D_IPREV = 22
D_PI_INT = 23
D_PER_START = 24
D_Q_START = 25
D_XAVG = 26
D_PER_RUNNING = 27
D_NEXT_SAMPLE = 28
D_SAMPLE_IDX = 29
D_AVG_IDX = 30
D_CHOP_DUTY = 31
D_BOOST_END = 32
D_N_STEPS = 33
D_SAMPLE_DT = 34
D_PREV_PERIOD = 35
D_SAMPLE_T0 = 36
D_N_FORCED = 37  # steps forced by the no-progress guard (0 unless the kernel has a bug)
# Integrals of the terminal current (A s) and voltage (V s) since t = 0, for interval
# means. Integrated by RK4 with y (as the 6th/7th component of the step tuple) but kept
# here, so y keeps its N_Y = 5 layout; they do not feed back into the dynamics.
D_QI = 38
D_QV = 39
# Slow ladder current i_b of the eddy_ladder emulator form, A (0 when off). Integrated by
# RK4 with y as the 8th component of the step tuple, kept here like D_QI.
D_IB = 40
D_VNEG = 41      # magnitude of the clamp voltage of PH_CLAMP, V
D_IMIN = 42      # running minimum of the sampled current after the dip ('dip_rise'), A
N_D = 43

# Output channels of recorded samples.
O_V = 0
O_I = 1
O_X = 2
O_XDOT = 3
O_DT = 4
O_MODE = 5
O_QX = 6       # integrals y[Y_Q], d[D_QI], d[D_QV] at the sample (interval means)
O_QI = 7
O_QV = 8
N_OUT = 9

# Columns of a bank sample row (:func:`bank_sample`).
S_T = 0
S_V = 1
S_I = 2
S_X = 3
S_XDOT = 4
S_XAVG = 5
S_FLOW = 6
S_DUTY = 7
S_FREQ = 8
S_PSUP = 9
S_POUT = 10
S_DT = 11
S_I_MEAN = 12   # mean terminal current over the interval since the previous sample, A
S_V_MEAN = 13   # mean terminal voltage over that interval, V
N_S = 14
# Interval state per valve (columns of ``iv``): start time, integrals of i and v at the
# start, the last means, and whether an interval has ended yet (1.0).
IV_T0 = 0
IV_QI0 = 1
IV_QV0 = 2
IV_I = 3
IV_V = 4
IV_DONE = 5
N_IV = 6


# --------------------------------------------------------------------------------------
# Argument checks: the compiled code takes C-contiguous float64 arrays (the ahead-of-time
# module has exactly these types); arrays it writes into must be such arrays already.
# --------------------------------------------------------------------------------------
def _vec(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _inout(a: np.ndarray, name: str) -> np.ndarray:
    if not (isinstance(a, np.ndarray) and a.dtype == np.float64
            and a.flags.c_contiguous and a.flags.writeable):
        raise TypeError(f'{name} must be a writeable C-contiguous float64 array (the kernel '
                        f'writes into it), got {type(a).__name__} '
                        f'{getattr(a, "dtype", "")}')
    return a


# --------------------------------------------------------------------------------------
# Single runs and the streaming state
# --------------------------------------------------------------------------------------
def derive_parameters(raw: np.ndarray) -> np.ndarray:
    """Derived parameters (``P_*``, shape (N_P,)) of a raw vector in PARAMETER_FIELDS order."""
    return _backend().derive_parameters(_vec(raw))


def new_drive_state(supply_voltage_v: float, duty: float, period_s: float,
                    first_period_start_s: float = 0.0, supply_pressure_pa: float = 0.0,
                    output_pressure_pa: float = 0.0, sample_dt_s: float = np.inf,
                    first_sample_s: float = 0.0) -> np.ndarray:
    """Initial discrete state: valve closed at rest, capacitor empty, PWM not yet started.

    The one initialisation of the drive state (the batches and
    :func:`valve_model_pkg.model.simulate_trace_batch` call its compiled body).

    Parameters
    ----------
    supply_voltage_v : float
        Driver supply voltage, V (the coil voltage of a bare coil in its supply phase).
    duty : float
        Main PWM duty in [0, 1] of the first period.
    period_s : float
        Main PWM period, s (inf: one endless period, a step or a bare-coil trace).
    first_period_start_s : float
        Start (rising edge) of the first main PWM period, s.
    supply_pressure_pa, output_pressure_pa : float
        Gauge pressures, Pa.
    sample_dt_s : float
        Samples are recorded at ``first_sample_s + k * sample_dt_s`` (none if inf).
    first_sample_s : float
        First sample time, s.

    Returns
    -------
    numpy.ndarray, shape (N_D,)
    """
    return _backend().new_drive_state(
        float(supply_voltage_v), float(duty), float(period_s), float(first_period_start_s),
        float(supply_pressure_pa), float(output_pressure_pa), float(sample_dt_s),
        float(first_sample_s))


def advance(p: np.ndarray, e: np.ndarray, y: np.ndarray, d: np.ndarray, t_end: float,
            h_free: float = DEFAULT_H_FREE_S, h_stop: float = DEFAULT_H_STOP_S,
            out: np.ndarray | None = None, avg_out: np.ndarray | None = None) -> None:
    """Integrate in place from ``d[D_T]`` to ``t_end`` (s); records into ``out``/``avg_out``.

    Parameters
    ----------
    p : numpy.ndarray, shape (N_P,)
        Derived parameters (:func:`derive_parameters`).
    e : numpy.ndarray, shape (N_E,)
        ``ElectronicsConfig.to_vector()``.
    y : numpy.ndarray, shape (N_Y,)
        Continuous state [i_m (A), x (m), x_dot (m/s), dT (K), q (m s)], updated in place.
    d : numpy.ndarray, shape (N_D,)
        Discrete state (:func:`new_drive_state`), updated in place.
    t_end : float
        End time, s.
    h_free, h_stop : float
        Maximum RK4 step with the spool moving / held, s.
    out : numpy.ndarray, shape (n_samples, N_OUT), optional
        Sample buffer (columns ``O_*``: V, i, x, x_dot, dT, mode, q, q_i, q_v).
    avg_out : numpy.ndarray, shape (n_periods,), optional
        Receives the period-average position of each completed main PWM period, m.
    """
    out = np.zeros((0, N_OUT)) if out is None else _inout(out, 'out')
    avg_out = np.zeros(0) if avg_out is None else _inout(avg_out, 'avg_out')
    _backend().advance(_vec(p), _vec(e), _inout(y, 'y'), _inout(d, 'd'), float(t_end),
                       float(h_free), float(h_stop), out, avg_out)


def command(d: np.ndarray, e: np.ndarray, duty: float, period_s: float) -> None:
    """Apply a main PWM command at the current time ``d[D_T]`` (kernel_jit._command)."""
    _backend().command(float(d[D_T]), _inout(d, 'd'), _vec(e), float(duty), float(period_s))


# --------------------------------------------------------------------------------------
# Batches: rows spread over threads
# --------------------------------------------------------------------------------------
_pool: ThreadPoolExecutor | None = None
_pool_pid = 0
_pool_lock = threading.Lock()


def batch_threads() -> int:
    """Threads a batch runs on: numba's thread count where numba has set one, else the CPUs.

    ``NUMBA_NUM_THREADS`` (the process workers of maps and fleets set it to 1) and
    ``numba.set_num_threads`` keep their meaning for batches on either kernel backend.
    """
    parallel = sys.modules.get('numba.np.ufunc.parallel')
    if parallel is not None and getattr(parallel, '_is_initialized', False):
        return int(sys.modules['numba'].get_num_threads())
    env = os.environ.get('NUMBA_NUM_THREADS', '').strip()
    if env.isdigit() and int(env) > 0:
        return int(env)
    return len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') \
        else os.cpu_count() or 1


def _thread_pool() -> ThreadPoolExecutor:
    from concurrent.futures import ThreadPoolExecutor  # (only batches need it)

    global _pool, _pool_pid
    with _pool_lock:
        if _pool is None or _pool_pid != os.getpid():  # a forked child has no threads
            _pool = ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 1),
                                       thread_name_prefix='valve-kernel')
            _pool_pid = os.getpid()
        return _pool


def _run_rows(rows: Callable[..., None], n_rows: int, args: tuple, parallel: bool) -> None:
    """Call ``rows(*args, r0, r1)`` over 0 <= r < n_rows, on several threads if allowed.

    Raises
    ------
    KernelInputError
        The compiled rows divided by zero: an input they cannot integrate (a zero-length
        interval or period) that the checks before the call did not catch.
    """
    try:
        _run_rows_on_threads(rows, n_rows, args, parallel)
    except ZeroDivisionError as err:
        raise KernelInputError(
            f'model kernel {getattr(rows, "__name__", "rows").lstrip("_")}: division by zero '
            f'in a batch of {n_rows} runs: the input holds a zero-length interval or period, '
            'or a parameter that is zero where the model divides by it') from err


def _run_rows_on_threads(rows: Callable[..., None], n_rows: int, args: tuple,
                         parallel: bool) -> None:
    workers = min(batch_threads(), n_rows) if parallel else 1
    if workers <= 1:
        rows(*args, 0, n_rows)
        return
    # small chunks taken in turn, so that runs of unequal cost still share out evenly
    chunk = max(1, n_rows // (8 * workers))
    starts = iter(range(0, n_rows, chunk))
    take = threading.Lock()

    def work() -> None:
        while True:
            with take:
                r0 = next(starts, None)
            if r0 is None:
                return
            rows(*args, r0, min(r0 + chunk, n_rows))

    pool = _thread_pool()
    for job in [pool.submit(work) for _ in range(workers)]:
        job.result()


def step_batch(raw: np.ndarray, e: np.ndarray, voltage: np.ndarray, p_sup: np.ndarray,
               p_out: np.ndarray, duration: float, step_time: float, sample_dt: float,
               n_samples: int, h_free: float = DEFAULT_H_FREE_S,
               h_stop: float = DEFAULT_H_STOP_S) -> tuple[np.ndarray, np.ndarray]:
    """Voltage-step responses of many parameter vectors in parallel (see simulation.py)."""
    raw = _vec(raw)
    n = raw.shape[0]
    cur = np.zeros((n, n_samples))
    pos = np.zeros((n, n_samples))
    _run_rows(_backend().step_rows, n,
              (raw, _vec(e), _vec(voltage), _vec(p_sup), _vec(p_out), float(duration),
               float(step_time), float(sample_dt), float(h_free), float(h_stop), cur, pos),
              True)
    return cur, pos


def pwm_batch(raw: np.ndarray, e: np.ndarray, supply_v: np.ndarray, duty: np.ndarray,
              period: np.ndarray, p_sup: np.ndarray, p_out: np.ndarray, n_periods: int,
              h_free: float = DEFAULT_H_FREE_S, h_stop: float = DEFAULT_H_STOP_S
              ) -> np.ndarray:
    """Per-period average positions (n_runs, n_periods) of many PWM runs in parallel."""
    raw = _vec(raw)
    n = raw.shape[0]
    avg = np.zeros((n, n_periods))
    _run_rows(_backend().pwm_rows, n,
              (raw, _vec(e), _vec(supply_v), _vec(duty), _vec(period), _vec(p_sup),
               _vec(p_out), float(h_free), float(h_stop), avg), True)
    return avg


#: Shortest main PWM period the kernel integrates [s]: a period start must move the time
#: of a run (a period below the float resolution of t would end where it starts); 1 ns is
#: above the resolution of any run shorter than 10^6 s and far below any drive's period.
MIN_PERIOD_S = 1e-9


def check_trace_rows(seg_t: np.ndarray, seg_period: np.ndarray, t_samp: np.ndarray) -> None:
    """Refuse trace inputs the kernel cannot integrate, naming the array, index and value.

    Parameters
    ----------
    seg_t : numpy.ndarray, shape (k,)
        Input change times [s]: finite, from 0 on, strictly increasing (a zero-length
        input interval is merged by the caller, never handed over).
    seg_period : numpy.ndarray, shape (k,)
        Main PWM period of each input [s]: at least :data:`MIN_PERIOD_S`, or ``inf``
        without a main PWM.
    t_samp : numpy.ndarray, shape (n,)
        Sample times [s]: finite, from 0 on, strictly increasing.

    Raises
    ------
    KernelInputError
    """
    for name, t in (('input change times', seg_t), ('sample times', t_samp)):
        bad = np.flatnonzero(~np.isfinite(t) | (t < 0.0))
        if bad.size:
            raise KernelInputError(f'model kernel: {name}[{bad[0]}] = {float(t[bad[0]]):.9g} s '
                                   'is not a finite time from 0 on')
        step = np.flatnonzero(np.diff(t) <= 0.0)
        if step.size:
            k = int(step[0]) + 1
            raise KernelInputError(
                f'model kernel: {name}[{k}] = {float(t[k]):.9g} s does not follow '
                f'{float(t[k - 1]):.9g} s: a zero-length interval (merge it before the run)')
    bad = np.flatnonzero(~(seg_period >= MIN_PERIOD_S))
    if bad.size:
        raise KernelInputError(
            f'model kernel: PWM period[{bad[0]}] = {float(seg_period[bad[0]]):.9g} s is shorter '
            f'than {MIN_PERIOD_S:g} s: a period of (nearly) zero length')


def trace_batch(raw: np.ndarray, e: np.ndarray, seg_t: np.ndarray, seg_vs: np.ndarray,
                seg_duty: np.ndarray, seg_period: np.ndarray, p_sup: np.ndarray,
                p_out: np.ndarray, t_samp: np.ndarray, h_free: float, h_stop: float,
                out: np.ndarray, stats: np.ndarray, parallel: bool = True,
                seg_psup: np.ndarray | None = None,
                seg_pout: np.ndarray | None = None) -> None:
    """Runs under piecewise-constant inputs, one ``out[r]`` row per sample time (in place).

    Input ``k`` (supply voltage V, pending duty, pending period s and, if ``seg_psup``,
    ``seg_pout`` are given, the gauge pressures Pa) applies from ``seg_t[k]`` (the first
    from t = 0); without them run r has the pressures ``p_sup[r]``, ``p_out[r]``
    throughout. ``out`` has shape (n_runs, n_samples, N_OUT), ``stats`` (n_runs, 2)
    receives the step count and the forced-step count. With ``parallel`` False the runs
    go one after the other on the calling thread (without the GIL, so that several
    threads of the caller can each run a batch).
    """
    raw = _vec(raw)
    none = np.zeros(0)
    check_trace_rows(np.asarray(seg_t, dtype=float), np.asarray(seg_period, dtype=float),
                     np.asarray(t_samp, dtype=float))
    _run_rows(_backend().trace_rows, raw.shape[0],
              (raw, _vec(e), _vec(seg_t), _vec(seg_vs), _vec(seg_duty), _vec(seg_period),
               none if seg_psup is None else _vec(seg_psup),
               none if seg_pout is None else _vec(seg_pout), _vec(p_sup), _vec(p_out),
               _vec(t_samp), float(h_free), float(h_stop), _inout(out, 'out'),
               _inout(stats, 'stats')), parallel)


# --------------------------------------------------------------------------------------
# Banks of streaming valves (model.bank.ValveBank)
# --------------------------------------------------------------------------------------
def bank_advance(p: np.ndarray, e: np.ndarray, y: np.ndarray, d: np.ndarray,
                 t_end: np.ndarray, h_free: float = DEFAULT_H_FREE_S,
                 h_stop: float = DEFAULT_H_STOP_S) -> None:
    """Advance every valve of a bank in place: row r of y, d to ``t_end[r]`` (s).

    ``p`` (n, N_P), ``e`` (n, N_E), ``y`` (n, N_Y), ``d`` (n, N_D), ``t_end`` (n,), all
    C-contiguous float64.
    """
    _backend().bank_advance(_vec(p), _vec(e), _inout(y, 'y'), _inout(d, 'd'), _vec(t_end),
                            float(h_free), float(h_stop))


def bank_sample(p: np.ndarray, e: np.ndarray, y: np.ndarray, d: np.ndarray,
                orifice: np.ndarray, atmosphere_pa: float, iv: np.ndarray,
                out: np.ndarray) -> None:
    """Fill ``out`` (n, N_S) with the state of every valve (kernel_jit._bank_sample)."""
    _backend().bank_sample(_vec(p), _vec(e), _vec(y), _vec(d), _vec(orifice),
                           float(atmosphere_pa), _inout(iv, 'iv'), _inout(out, 'out'))
