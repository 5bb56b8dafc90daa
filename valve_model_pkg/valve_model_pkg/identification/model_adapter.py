"""Measurements -> the model's one simulation entry (:func:`model.simulate_trace_batch`).

The identification simulates a whole matrix of parameter vectors under a *measured* coil
voltage (a pulse, a PWM train, a bench's own waveform), sampled at the measurement's own
times. The model offers exactly that (:func:`valve_model_pkg.model.simulate_trace_batch`
with :meth:`~valve_model_pkg.model.InputTrace.coil_voltage`, the bare coil); this module
only turns a :class:`Measurement` into that call, once per file (:func:`prepare_trace`),
and simulates it (:func:`simulate_measurement`), so the identification simulates exactly
the model that ``valve_simulate`` and ``valve_map`` use.

The measured voltage is read as a zero-order hold: sample ``k``'s value applies from
``t[k]`` to ``t[k+1]``. Consecutive samples within a tolerance (0.5 % of the largest
magnitude) form one segment at their mean level, so a measured (slightly noisy) voltage
column does not create an edge per sample. The valve starts at rest (closed, no current)
at ``t = 0``. Samples on a uniform grid (missing rows allowed) are simulated on that
grid; others (strictly increasing, from t >= 0) at their own times, as the model allows any
sample times; the rest are interpolated from a grid of at most 20 us.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..model import (DEFAULT_H_FREE_S, DEFAULT_H_STOP_S, PARAMETER_FIELDS,
                     ElectronicsConfig, InputTrace, simulate_trace_batch)
from ..errors import KernelInputError, ModelAdapterError
from .measurement import Measurement

__all__ = ['TraceSetup', 'interval_segments', 'prepare_trace', 'simulate_measurement',
           'FIELD_INDEX']

#: Column of each ValveParameters field in a raw parameter matrix.
FIELD_INDEX = {name: i for i, name in enumerate(PARAMETER_FIELDS)}

_VOLTAGE_TOLERANCE = 0.005
# Finest output grid used when the measurement's times are not on a uniform grid.
_MAX_GRID_DT_S = 20e-6


@dataclass(frozen=True)
class TraceSetup:
    """Everything the kernel needs for one measurement, prepared once per file.

    Attributes
    ----------
    seg_t0_s : numpy.ndarray, shape (n_seg,)
        Start time of each constant-voltage segment [s] (the first is 0).
    seg_v : numpy.ndarray, shape (n_seg,)
        Voltage of each segment [V].
    t_end_s : float
        End of the simulation [s] (the last sample time).
    grid_t0_s, grid_dt_s : float
        Output grid ``grid_t0_s + k grid_dt_s`` [s].
    n_grid : int
        Number of grid samples (0: simulated at ``t_s`` itself).
    index : numpy.ndarray or None, shape (n,)
        Grid index of each measured sample when the samples lie on the grid, else None.
    t_s : numpy.ndarray, shape (n,)
        The measured sample times [s] (for interpolation).
    supply_pressure_pa, output_pressure_pa : float
        Pressures, gauge [Pa].
    h_stop_s : float
        Kernel step while the spool rests on a stop [s].
    drive : InputTrace or None
        Main PWM commands through the drive electronics (operation and pwm records);
        ``None`` drives the bare coil with ``seg_v``.
    sampling : str
        ``instant`` or ``interval_mean`` (how the record's current was sampled).
    """

    seg_t0_s: np.ndarray
    seg_v: np.ndarray
    t_end_s: float
    grid_t0_s: float
    grid_dt_s: float
    n_grid: int
    index: np.ndarray | None
    t_s: np.ndarray
    supply_pressure_pa: float
    output_pressure_pa: float
    h_stop_s: float
    drive: InputTrace | None = None
    sampling: str = 'instant'

    @cached_property
    def coil_trace(self) -> InputTrace:
        """The coil voltage ``seg_v`` from ``seg_t0_s`` on as the model's input (built once:
        a search simulates the same record thousands of times)."""
        return InputTrace.coil_voltage(self.seg_t0_s, self.seg_v)

    @cached_property
    def grid_s(self) -> np.ndarray:
        """The output grid ``grid_t0_s + k grid_dt_s``, k < ``n_grid`` [s]."""
        return self.grid_t0_s + self.grid_dt_s * np.arange(self.n_grid)


def _segments(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group the zero-order-held voltage into constant segments (see module notes)."""
    tol = _VOLTAGE_TOLERANCE * max(float(np.max(np.abs(v))), 1e-3)
    starts = [0]
    lo = hi = v[0]
    for k in range(1, v.size):
        lo2, hi2 = min(lo, v[k]), max(hi, v[k])
        if hi2 - lo2 > tol:
            starts.append(k)
            lo = hi = v[k]
        else:
            lo, hi = lo2, hi2
    starts_a = np.array(starts)
    ends = np.append(starts_a[1:], v.size)
    levels = np.array([v[a:b].mean() for a, b in zip(starts_a, ends)])
    t0 = t[starts_a].astype(float)
    t0[0] = 0.0  # the valve is at rest from t = 0 under the first level
    return t0, levels


#: An interval whose mean lies between its neighbours' means, which differ by more than
#: this share of the largest |mean|, holds one edge from the level before to the level
#: after (:func:`interval_segments`).
EDGE_MIN_SHARE = 0.2


def interval_segments(t: np.ndarray, v_mean: np.ndarray, *, place_edges: bool = True
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The bare coil's input from interval-mean voltages over ``(t[k-1], t[k]]`` (over
    ``[0, t[0]]`` for the first), with the measured integral over every interval.

    Each interval is held at its mean (zero-order hold), except, with ``place_edges``, an
    interval between a level before and a different level after (the neighbours' means
    differ by more than :data:`EDGE_MIN_SHARE` of the largest |mean| and its own mean lies
    between them): the drive switched within it, so it holds the level before for the
    fraction ``a = (v_after - v_k) / (v_after - v_before)`` of the interval and the level
    after for the rest. Either way ``a v_before + (1 - a) v_after = v_k``: over every
    interval the held input has the measured integral of the terminal voltage, so the
    model's flux linkage obeys the interval balance ``mean(u) dt = R mean(i) dt +
    delta psi`` (eq. 1) with the measured ``mean(u)``; placing the edge removes most of
    the zero-order hold's error in the interval's mean current (about ``u dt a (1 - a) /
    (2 L)``, some 20 mA for 24 V over 1 ms at 0.14 H).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        Interval ends [s], strictly increasing, from t >= 0.
    v_mean : numpy.ndarray, shape (n,)
        Mean terminal voltage over each interval [V].
    place_edges : bool
        Place one edge in intervals between two levels (else hold every mean).

    Returns
    -------
    seg_t0_s, seg_v : numpy.ndarray, shape (n_seg,)
        Segment starts [s] (the first is 0) and levels [V], equal neighbours merged.
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(v_mean, dtype=float)
    begin = np.concatenate(([0.0], t[:-1]))
    starts = [begin]
    levels = [v]
    if place_edges and v.size >= 3:
        before, mid, after = v[:-2], v[1:-1], v[2:]
        span = after - before
        big = np.abs(span) > EDGE_MIN_SHARE * max(float(np.max(np.abs(v))), 1e-9)
        with np.errstate(invalid='ignore', divide='ignore'):
            a = np.where(big, (after - mid) / np.where(big, span, 1.0), -1.0)
        k = np.flatnonzero((a > 0.0) & (a < 1.0)) + 1
        # interval k: the level before from its start, the level after from the edge
        levels[0] = v.copy()
        levels[0][k] = v[k - 1]
        starts.append(begin[k] + a[k - 1] * (t[k] - begin[k]))
        levels.append(v[k + 1])
    seg_t = np.concatenate(starts)
    seg_v = np.concatenate(levels)
    order = np.argsort(seg_t, kind='stable')
    seg_t, seg_v = seg_t[order], seg_v[order]
    # an empty first interval (t[0] = 0) or an edge at an interval start: the later wins
    keep = np.concatenate((seg_t[1:] > seg_t[:-1], [True]))
    seg_t, seg_v = seg_t[keep], seg_v[keep]
    change = np.concatenate(([True], seg_v[1:] != seg_v[:-1]))
    seg_t, seg_v = seg_t[change], seg_v[change]
    seg_t[0] = 0.0
    return seg_t, seg_v


def _interval_mean_setup(m: Measurement, h_stop_s: float | None,
                         keep: np.ndarray | None) -> TraceSetup:
    """The bare coil driven by interval-mean voltages, sampled at the record's own times
    (as interval means when the current is)."""
    seg_t0, seg_v = interval_segments(m.t_s, m.voltage_v)
    t = m.t_s if keep is None else m.t_s[keep]
    return TraceSetup(seg_t0_s=seg_t0, seg_v=seg_v, t_end_s=float(t[-1]),
                      grid_t0_s=float(t[0]), grid_dt_s=float(np.median(np.diff(t))),
                      n_grid=0, index=None, t_s=t,
                      supply_pressure_pa=float(m.supply_pressure_pa),
                      output_pressure_pa=float(m.output_pressure_pa),
                      h_stop_s=float(DEFAULT_H_STOP_S if h_stop_s is None else h_stop_s),
                      sampling=m.sampling)


def _rest_step_s(duration_s: float, sample_dt_s: float) -> float:
    """Kernel step while the spool rests [s] (:func:`prepare_trace`): the kernel's default,
    or up to 500 us (at most a sample period) for a trace of 0.5 s or more."""
    if duration_s < 0.5:
        return DEFAULT_H_STOP_S
    return max(DEFAULT_H_STOP_S, min(500e-6, sample_dt_s))


def prepare_trace(m: Measurement, *, h_stop_s: float | None = None,
                  keep: np.ndarray | None = None) -> TraceSetup:
    """Prepare a measurement for :func:`simulate_measurement`.

    Parameters
    ----------
    m : Measurement
        The measured trace (its voltage drives the model; its times are where the current
        is sampled).
    h_stop_s : float, optional
        Kernel step while the spool rests [s]. Default: the kernel's default, or up to
        500 us for multi-second traces, where the slow RL dynamics (tau ~ 10 ms) allow it
        and it keeps the cost of a heating experiment down.
    keep : numpy.ndarray of bool, optional
        Samples at which to report the current (default all). The voltage edges always
        come from every sample.

    Raises
    ------
    ModelAdapterError
        If the supply pressure is unknown.
    """
    if m.supply_pressure_pa is None:
        raise ModelAdapterError(
            f'{m.source}: no supply_pressure_pa in the metadata; the model needs it')
    if m.drive is not None:
        # Through the electronics: the model is sampled exactly at the record's times
        # (interval means over the record's own intervals), no grid.
        d = m.drive
        t = m.t_s if keep is None else m.t_s[keep]
        return TraceSetup(
            seg_t0_s=np.zeros(1), seg_v=np.zeros(1), t_end_s=float(t[-1]),
            grid_t0_s=float(t[0]), grid_dt_s=float(np.median(np.diff(t))), n_grid=t.size,
            index=None, t_s=t, supply_pressure_pa=float(m.supply_pressure_pa),
            output_pressure_pa=float(m.output_pressure_pa),
            h_stop_s=float(DEFAULT_H_STOP_S if h_stop_s is None else h_stop_s),
            drive=InputTrace.pwm_commands(d.t_s, d.duty, d.pwm_frequency_hz,
                                          d.supply_voltage_v),
            sampling=m.sampling)
    if m.voltage_hold == 'interval_mean':
        if h_stop_s is None and not m.in_service:
            # a bench step driven by its mean voltage rests as long as a sampled one;
            # records in service keep the kernel's default (their chopped means switch
            # within most intervals of a PWM period)
            h_stop_s = _rest_step_s(m.duration_s, float(np.median(np.diff(m.t_s))))
        return _interval_mean_setup(m, h_stop_s, keep)
    seg_t0, seg_v = _segments(m.t_s, m.voltage_v)
    t = m.t_s if keep is None else m.t_s[keep]
    dt = float(np.median(np.diff(t)))
    # Samples on a uniform grid (missing rows allowed) are read straight off the grid.
    n_float = (t - t[0]) / dt
    n_int = np.round(n_float)
    on_grid = bool(np.max(np.abs(n_float - n_int)) < 1e-3) and dt <= 1e-2
    if on_grid:
        grid_dt, index = dt, n_int.astype(np.int64)
        n_grid = int(index[-1]) + 1
    elif t[0] >= 0.0 and bool(np.all(np.diff(t) > 0.0)):
        # Off a uniform grid (a bag's receive stamps): the model samples at any times (its
        # integrator lands on each), so it is sampled at the record's own times; n_grid = 0
        # marks it. (A fine 20 us grid plus interpolation cost 50 times more for 1 kHz.)
        grid_dt, index, n_grid = dt, None, 0
    else:
        grid_dt = min(dt, _MAX_GRID_DT_S)
        n_grid = int(math.floor((t[-1] - t[0]) / grid_dt)) + 2
        index = None
    if h_stop_s is None:
        h_stop_s = _rest_step_s(m.duration_s, grid_dt)
    return TraceSetup(seg_t0_s=seg_t0, seg_v=seg_v, t_end_s=float(t[-1]),
                      grid_t0_s=float(t[0]), grid_dt_s=grid_dt, n_grid=n_grid, index=index,
                      t_s=t, supply_pressure_pa=float(m.supply_pressure_pa),
                      output_pressure_pa=float(m.output_pressure_pa),
                      h_stop_s=float(h_stop_s))


def simulate_measurement(raw: np.ndarray, setup: TraceSetup, *,
                         h_free_s: float = DEFAULT_H_FREE_S, parallel: bool = True,
                         electronics: ElectronicsConfig | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Simulate many parameter vectors under one measurement (its voltage or commands).

    Parameters
    ----------
    raw : numpy.ndarray, shape (n_runs, len(PARAMETER_FIELDS))
        Parameter vectors in ``PARAMETER_FIELDS`` order (``ValveParameters.to_vector``).
    setup : TraceSetup
        From :func:`prepare_trace`.
    h_free_s : float
        Kernel step while the spool moves [s].
    parallel : bool
        Allow numba's thread pool (for batches of at least ``PARALLEL_MIN_BATCH``). False
        runs on the calling thread without the GIL, so several Python threads can
        simulate at once (numba's default threading layer must not be entered from two
        threads).

    Returns
    -------
    current_a, position_m : numpy.ndarray, shape (n_runs, n_samples)
        Simulated terminal current [A] and spool position [m] at the measured times.

    Notes
    -----
    A multi-second record is integrated with steps of up to 500 us while the spool rests
    (:func:`prepare_trace`), which the coil's time constant L/R of milliseconds allows.
    A parameter vector of the search with a far smaller incremental inductance (a low
    permeability with strong saturation: L/R ~ 0.1 ms) makes that RK4 step unstable (it
    diverges beyond 2.8 L/R) and the kernel refuses the run (``KernelInputError``); the
    batch is then run row by row, and each row the step cannot integrate runs again with
    :data:`~valve_model_pkg.model.DEFAULT_H_STOP_S`, then ``h_free_s``. The other rows
    keep their results bit for bit (the rows of a batch are independent runs).
    """
    raw = np.ascontiguousarray(np.atleast_2d(raw), dtype=np.float64)
    if raw.shape[1] != len(PARAMETER_FIELDS):
        raise ModelAdapterError(
            f'parameter matrix has {raw.shape[1]} columns, the model has '
            f'{len(PARAMETER_FIELDS)} fields')
    try:
        return _simulate(raw, setup, setup.h_stop_s, h_free_s, parallel, electronics)
    except KernelInputError:
        if setup.h_stop_s <= DEFAULT_H_STOP_S:
            raise
    rows = [_simulate_row_stably(raw[r:r + 1], setup, h_free_s, electronics)
            for r in range(raw.shape[0])]
    return (np.concatenate([c for c, _ in rows]), np.concatenate([x for _, x in rows]))


def _simulate_row_stably(raw_row: np.ndarray, setup: TraceSetup, h_free_s: float,
                         electronics: ElectronicsConfig | None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """One row with the setup's rest step, else with shorter ones (see
    :func:`simulate_measurement`); the last refusal is raised."""
    steps = [setup.h_stop_s, DEFAULT_H_STOP_S, min(h_free_s, DEFAULT_H_STOP_S)]
    for k, h_stop_s in enumerate(steps):
        try:
            return _simulate(raw_row, setup, h_stop_s, h_free_s, False, electronics)
        except KernelInputError:
            if k == len(steps) - 1:
                raise
    raise AssertionError('unreachable')


def _simulate(raw: np.ndarray, setup: TraceSetup, h_stop_s: float, h_free_s: float,
              parallel: bool, electronics: ElectronicsConfig | None
              ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`simulate_measurement` with the rest step ``h_stop_s`` [s]."""
    n = raw.shape[0]
    if setup.drive is not None:
        res = simulate_trace_batch(
            raw, setup.drive, setup.t_s, electronics=electronics or ElectronicsConfig(),
            sampling=setup.sampling, supply_pressure_pa=setup.supply_pressure_pa,
            output_pressure_pa=setup.output_pressure_pa, h_free_s=float(h_free_s),
            h_stop_s=h_stop_s, validate=False, parallel=parallel)
        return res.coil_current_a, res.spool_position_m
    if setup.n_grid == 0:
        res = simulate_trace_batch(
            raw, setup.coil_trace, setup.t_s,
            sampling=setup.sampling, supply_pressure_pa=setup.supply_pressure_pa,
            output_pressure_pa=setup.output_pressure_pa, h_free_s=float(h_free_s),
            h_stop_s=h_stop_s, validate=False, parallel=parallel)
        return res.coil_current_a, res.spool_position_m
    grid = setup.grid_s
    res = simulate_trace_batch(
        raw, setup.coil_trace, grid,
        supply_pressure_pa=setup.supply_pressure_pa,
        output_pressure_pa=setup.output_pressure_pa, h_free_s=float(h_free_s),
        h_stop_s=h_stop_s, validate=False, parallel=parallel)
    cur, pos = res.coil_current_a, res.spool_position_m
    if setup.index is not None:
        return cur[:, setup.index], pos[:, setup.index]
    ci = np.empty((n, setup.t_s.size))
    pi = np.empty((n, setup.t_s.size))
    for r in range(n):
        ci[r] = np.interp(setup.t_s, grid, cur[r])
        pi[r] = np.interp(setup.t_s, grid, pos[r])
    return ci, pi
