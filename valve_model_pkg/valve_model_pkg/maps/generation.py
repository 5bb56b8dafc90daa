"""Generate the static duty map: x_avg / x_max at periodic steady state on a grid.

Every grid point (duty, supply pressure, PWM frequency) is simulated with the full model,
drive electronics on, from a closed valve at rest, until its period averages meet the
periodic-steady-state criterion of :mod:`.steady_state`. Each point is simulated with the
model's streaming API one PWM period at a time and stopped as soon as it is steady, so it
costs exactly the periods it needs (the model's batch period means,
``simulate_trace_batch(..., n_periods=n)``, cannot continue a run: a steady-state search
on them restarts longer runs from the beginning, 1.6-2.2 times the needed periods on this
grid). The points
are spread over one worker process per core (:mod:`.worker`); a worker is restarted if a
model call never returns, so a model fault cannot hang the generator; such events are
noted in the file.

Then, for every curve, the dead band edge (between the last closed and the first open grid
duty) and the saturation edge (between the last grid duty that leaves the open stop and
the first that does not) are refined by bisection to ``edge_tolerance`` (default 0.1 %
duty), again at periodic steady state, and steep or curved segments are refined
adaptively (:class:`Refinement`) so that linear interpolation of the stored points is
accurate and jumps of the curve are found.
"""
from __future__ import annotations

import datetime as _dt
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .curves import DEFAULT_STOP_TOLERANCE, curve_features
from .dutymap import DutyMap
from ..errors import MapGenerationError
from .steady_state import SteadyState, SteadyStateCriterion

__all__ = ['MapGrid', 'GenerationStats', 'MapSimulator', 'Refinement', 'generate_map',
           'steady_positions', 'PAPER_GRID']

#: ``progress(done, total, message)``; ``done`` counts grid points (and refinement runs).
ProgressCallback = Callable[[int, int, str], None]


@dataclass(frozen=True)
class MapGrid:
    """The grid of a duty map.

    Attributes
    ----------
    duty : tuple of float
        Ascending duties [1] from 0 to 1.
    supply_pressures_pa : tuple of float
        Supply pressures, gauge [Pa].
    pwm_frequencies_hz : tuple of float
        Main PWM frequencies [Hz].
    output_pressure_pa : float
        Output pressure, gauge [Pa] (0: exhausting to atmosphere, as in the paper).
    """

    duty: tuple[float, ...] = tuple(np.round(np.linspace(0.0, 1.0, 101), 12))
    supply_pressures_pa: tuple[float, ...] = (0.0, 2.0e5, 4.0e5, 6.0e5)
    pwm_frequencies_hz: tuple[float, ...] = (20.0, 50.0, 100.0, 200.0)
    output_pressure_pa: float = 0.0

    @classmethod
    def regular(cls, duty_step: float = 0.01, supply_pressures_pa=(0.0, 2.0e5, 4.0e5, 6.0e5),
                pwm_frequencies_hz=(20.0, 50.0, 100.0, 200.0),
                output_pressure_pa: float = 0.0) -> MapGrid:
        """Duties 0, step, ..., 1 (``1 / duty_step`` must be an integer)."""
        n = round(1.0 / duty_step)
        if n < 1 or abs(n * duty_step - 1.0) > 1e-9:
            raise ValueError(f'1 / duty_step must be a whole number, got step {duty_step!r}')
        return cls(tuple(np.round(np.linspace(0.0, 1.0, n + 1), 12)),
                   tuple(float(p) for p in sorted(supply_pressures_pa)),
                   tuple(float(f) for f in sorted(pwm_frequencies_hz)),
                   float(output_pressure_pa))

    @property
    def n_points(self) -> int:
        return len(self.duty) * len(self.supply_pressures_pa) * len(self.pwm_frequencies_hz)


#: The grid a shipped map covers: 1 % steps, 0/2/4/6 bar, 20/50/100/200 Hz.
PAPER_GRID = MapGrid()


@dataclass
class GenerationStats:
    """What a generation cost.

    Attributes
    ----------
    runs : int
        Points simulated (grid, edge bisection and refinement).
    simulated_s : float
        Model time simulated over all runs [s].
    grid_periods_s : float
        Model time the grid points needed (sum over points of periods x period) [s].
    wall_s : float
        Wall time of the whole generation [s].
    grid_wall_s, refine_wall_s : float
        Wall time of the grid and of the edge refinement [s].
    unconverged : int
        Grid points that missed the steady-state criterion.
    subharmonic : int
        Grid points that settled to a cycle of more than one period.
    threads : int
        Worker processes.
    """

    runs: int = 0
    simulated_s: float = 0.0
    grid_periods_s: float = 0.0
    wall_s: float = 0.0
    grid_wall_s: float = 0.0
    refine_wall_s: float = 0.0
    unconverged: int = 0
    subharmonic: int = 0
    threads: int = 0
    extra: dict = field(default_factory=dict)


class MapSimulator:
    """Steady x_avg / x_max of operating points, on the model's public streaming API.

    The only place maps/ runs the model. Each point is simulated period by period until it
    meets the periodic-steady-state criterion, the points of a request together as one
    bank of valves (:func:`~valve_model_pkg.maps.worker.run_points_in_process`; the same
    results as :func:`~valve_model_pkg.maps.worker.steady_point` one by one). With
    ``isolate=True`` (the default) the points are spread over ``workers`` child processes
    (:class:`~valve_model_pkg.maps.worker.PointWorker`, one per core by default, forked
    from this process) that are restarted if a model call never returns; otherwise they run
    in this process.

    Use as a context manager (or call :meth:`close`) to stop the workers.

    Parameters
    ----------
    params : ValveParameters
    electronics : ElectronicsConfig, optional
    supply_voltage_v : float
    criterion : SteadyStateCriterion, optional
    isolate : bool
    workers : int, optional
        Worker processes (default: the number of CPUs).
    """

    def __init__(self, params, electronics=None, supply_voltage_v: float = 24.0,
                 criterion: SteadyStateCriterion | None = None, *, isolate: bool = True,
                 workers: int | None = None) -> None:
        import os

        from valve_model_pkg.model import ElectronicsConfig

        from .worker import PointWorker
        self.params = params
        self.electronics = ElectronicsConfig() if electronics is None else electronics
        self.supply_voltage_v = float(supply_voltage_v)
        self.criterion = criterion or SteadyStateCriterion()
        self.stats = GenerationStats()
        self._params_dict = params.to_dict()
        self._electronics_dict = self.electronics.to_dict()
        n = max(1, int(workers or os.cpu_count() or 1)) if isolate else 0
        self._workers = [PointWorker() for _ in range(n)]
        for w in self._workers:
            w.start()
        for w in self._workers:
            w.wait_ready()
        self.stats.threads = max(n, 1)

    @property
    def incidents(self) -> list[str]:
        """Model calls that did not return (and what was done instead)."""
        return [text for w in self._workers for text in w.incidents]

    def close(self) -> None:
        for w in self._workers:
            w.close()

    def __enter__(self) -> MapSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def steady(self, duty, freq, supply, output: float = 0.0) -> list[SteadyState]:
        """Periodic steady state of every point (arrays broadcast against ``duty``).

        A point the model never returned for gets a not-converged state with value NaN.
        """
        import threading

        from .worker import PointRequest, run_points_in_process
        duty = np.atleast_1d(np.asarray(duty, dtype=float))
        freq = np.broadcast_to(np.asarray(freq, dtype=float), duty.shape).copy()
        supply = np.broadcast_to(np.asarray(supply, dtype=float), duty.shape).copy()
        if duty.size == 0:
            return []
        req = PointRequest(self._params_dict, self._electronics_dict, self.supply_voltage_v,
                           float(output), self.criterion.as_dict(), duty, freq, supply)
        if not self._workers:
            results = run_points_in_process(req)
        else:
            # deal the points out like cards, longest periods first, for equal work
            order = np.argsort(-1.0 / freq, kind='stable')
            chunks = [order[k::len(self._workers)].tolist()
                      for k in range(len(self._workers))]
            results = [None] * duty.size
            errors: list[BaseException] = []

            def work(worker, idx: list[int]) -> None:
                try:
                    for i, s in zip(idx, worker.steady(req.subset(idx))):
                        results[i] = s
                except BaseException as err:  # noqa: BLE001 - re-raised below
                    errors.append(err)
            threads = [threading.Thread(target=work, args=(w, c), daemon=True)
                       for w, c in zip(self._workers, chunks) if c]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            if errors:
                raise MapGenerationError(f'model failed: {errors[0]}') from errors[0]
        self.stats.runs += duty.size
        self.stats.simulated_s += float(sum(s.periods / f for s, f in zip(results, freq)))
        return results


def steady_positions(params, electronics=None, duty=0.5, pwm_frequency_hz=50.0,
                     supply_pressure_pa=4.0e5, output_pressure_pa: float = 0.0, *,
                     criterion: SteadyStateCriterion | None = None,
                     supply_voltage_v: float = 24.0, isolate: bool = True
                     ) -> list[SteadyState]:
    """Steady x_avg / x_max of arbitrary points (arrays broadcast), e.g. for checks.

    Returns
    -------
    list of SteadyState
        One per point, in the broadcast order of the inputs.
    """
    d, f, p = (np.ravel(a).astype(float) for a in np.broadcast_arrays(
        np.asarray(duty, float), np.asarray(pwm_frequency_hz, float),
        np.asarray(supply_pressure_pa, float)))
    with MapSimulator(params, electronics, supply_voltage_v, criterion,
                      isolate=isolate) as sim:
        return sim.steady(d, f, p, output_pressure_pa)


@dataclass(frozen=True)
class Refinement:
    """Adaptive refinement of the curves between grid duties.

    A segment between neighbouring steady points is split at its midpoint (a new steady
    simulation) while it is wider than ``min_spacing`` and either rises by more than
    ``max_rise`` or the curve is not linear on it: the middle point of three neighbours
    lies more than ``interp_tolerance`` from the chord of the outer two. So linear
    interpolation of the stored points is good to about ``interp_tolerance`` wherever the
    curve is continuous, and a segment still rising by more than ``jump_threshold`` at the
    finest spacing is a jump of the curve (openings in between are not reachable).

    Attributes
    ----------
    interp_tolerance : float
        Fraction of x_max (default 0.005).
    max_rise : float
        Fraction of x_max (default 0.05).
    min_spacing : float
        Finest duty step (default 1/16 of 1 %).
    jump_threshold : float
        Fraction of x_max (default 0.02, the round-trip accuracy).
    max_levels : int
        Most bisection levels.
    """

    interp_tolerance: float = 0.005
    max_rise: float = 0.05
    min_spacing: float = 0.01 / 16
    jump_threshold: float = 0.02
    max_levels: int = 8

    def as_dict(self) -> dict:
        return {'interp_tolerance': self.interp_tolerance, 'max_rise': self.max_rise,
                'min_spacing': self.min_spacing, 'jump_threshold': self.jump_threshold,
                'max_levels': self.max_levels}


def _initial_segments(d: np.ndarray, x: np.ndarray, ref: Refinement) -> set[tuple[float, float]]:
    """Segments of one curve's points that need splitting (see :class:`Refinement`)."""
    out: set[tuple[float, float]] = set()
    wide = np.diff(d) > ref.min_spacing * 1.0001
    for k in range(d.size - 1):
        if wide[k] and abs(x[k + 1] - x[k]) > ref.max_rise:
            out.add((float(d[k]), float(d[k + 1])))
    for k in range(1, d.size - 1):
        chord = x[k - 1] + (x[k + 1] - x[k - 1]) * (d[k] - d[k - 1]) / (d[k + 1] - d[k - 1])
        if abs(x[k] - chord) > ref.interp_tolerance:
            for a, b in ((k - 1, k), (k, k + 1)):
                if wide[a] and abs(x[b] - x[a]) > ref.interp_tolerance:
                    out.add((float(d[a]), float(d[b])))
    return out


def generate_map(params, electronics=None, grid: MapGrid = PAPER_GRID, *,
                 criterion: SteadyStateCriterion | None = None, supply_voltage_v: float = 24.0,
                 refine_edges: bool = True, edge_tolerance: float = 1e-3,
                 refinement: Refinement | None = Refinement(),
                 stop_tolerance: float = DEFAULT_STOP_TOLERANCE,
                 progress: ProgressCallback | None = None, threads: int | None = None,
                 generator: dict | None = None, isolate: bool = True,
                 simulator: MapSimulator | None = None) -> tuple[DutyMap, GenerationStats]:
    """Simulate the static duty map on ``grid``.

    Parameters
    ----------
    params : ValveParameters
    electronics : ElectronicsConfig, optional
        Default ``ElectronicsConfig()`` (drive electronics on, as in the paper).
    grid : MapGrid
    criterion : SteadyStateCriterion, optional
    supply_voltage_v : float
    refine_edges : bool
        Bisect the dead band and saturation edges of every curve.
    edge_tolerance : float
        Width of the final bisection bracket [duty fraction].
    refinement : Refinement or None
        Adaptive refinement of steep or curved segments (None: grid only).
    stop_tolerance : float
        Average opening (fraction of x_max) within which a point counts as on a stop.
    progress : callable, optional
        ``progress(done, total, message)``, called after every curve and refinement step.
    threads : int, optional
        Worker processes (default: one per CPU).
    generator : dict, optional
        Extra provenance recorded in the file.
    isolate : bool
        Run the model in worker processes that are restarted if a call never returns.
    simulator : MapSimulator, optional
        Reuse a simulator (its parameters, electronics, criterion and voltage are used;
        it is not closed).

    Returns
    -------
    (DutyMap, GenerationStats)

    Raises
    ------
    MapGenerationError
        If the model fails.
    """
    own = simulator is None
    t_start = time.perf_counter()
    sim = simulator or MapSimulator(params, electronics, supply_voltage_v, criterion,
                                    isolate=isolate, workers=threads)
    try:
        return _generate(sim, grid, refine_edges, edge_tolerance, refinement, stop_tolerance,
                         progress, generator, t_start)
    finally:
        if own:
            sim.close()


@dataclass
class _Curves:
    """The map's curves while they are generated: grid values and the extra points."""

    duty: np.ndarray                 # (n_d,) grid duties [1]
    press: np.ndarray                # (n_p,) supply pressures, gauge [Pa]
    freqs: np.ndarray                # (n_f,) PWM frequencies [Hz]
    x: np.ndarray                    # (n_f, n_p, n_d) x_avg / x_max, NaN: not returned
    periods: np.ndarray              # (n_f, n_p, n_d) periods simulated
    converged: np.ndarray            # (n_f, n_p, n_d) steady-state criterion met
    cycles: np.ndarray               # (n_f, n_p, n_d) periods of the settled cycle
    extra: list[dict[float, float]]  # per curve (i * n_p + j): duty -> value off the grid

    def indices(self) -> list[tuple[int, int]]:
        """(frequency, pressure) index of every curve, frequency major."""
        return [(i, j) for i in range(self.freqs.size) for j in range(self.press.size)]

    def extra_at(self, i: int, j: int) -> dict[float, float]:
        return self.extra[i * self.press.size + j]


def _clipped(value: float) -> float:
    """A steady opening clipped to [0, 1]; NaN (the model did not return) stays NaN."""
    return min(max(value, 0.0), 1.0) if not math.isnan(value) else math.nan


def _grid_stage(sim: MapSimulator, grid: MapGrid, stop_tolerance: float,
                progress: ProgressCallback | None) -> _Curves:
    """Every grid point at periodic steady state, in one request to the workers (they
    share out the whole grid at once, with no wait for the slowest point of each curve)."""
    duty = np.asarray(grid.duty, dtype=float)
    press = np.asarray(grid.supply_pressures_pa, dtype=float)
    freqs = np.asarray(grid.pwm_frequencies_hz, dtype=float)
    n_f, n_p, n_d = freqs.size, press.size, duty.size
    c = _Curves(duty, press, freqs, np.zeros((n_f, n_p, n_d)),
                np.zeros((n_f, n_p, n_d), dtype=int), np.zeros((n_f, n_p, n_d), dtype=bool),
                np.zeros((n_f, n_p, n_d), dtype=int), [{} for _ in range(n_f * n_p)])
    t0 = time.perf_counter()
    all_states = sim.steady(np.tile(duty, n_f * n_p), np.repeat(freqs, n_p * n_d),
                            np.tile(np.repeat(press, n_d), n_f), grid.output_pressure_pa)
    done = 0
    for i, j in c.indices():
        start = (i * n_p + j) * n_d
        for k, st in enumerate(all_states[start:start + n_d]):
            c.x[i, j, k] = _clipped(st.value)
            c.periods[i, j, k] = st.periods
            c.converged[i, j, k] = st.converged
            c.cycles[i, j, k] = st.cycle
        sim.stats.grid_periods_s += float(np.sum(c.periods[i, j]) / freqs[i])
        done += n_d
        if progress:
            feat = curve_features(duty, c.x[i, j], stop_tolerance)
            progress(done, grid.n_points, f'{freqs[i]:g} Hz, {press[j] / 1e5:g} bar: dead band '
                                          f'{feat.dead_band_duty:.0%}, saturation '
                                          f'{feat.saturation_duty:.0%}, '
                                          f'max {c.periods[i, j].max()} periods')
    sim.stats.grid_wall_s = time.perf_counter() - t0
    return c


def _run_extra(sim: MapSimulator, grid: MapGrid, c: _Curves, ij: list[tuple[int, int]],
               dq: np.ndarray) -> np.ndarray:
    """Steady openings at duties ``dq`` of the curves ``ij``, kept as the curves' extra
    points; NaN where the model did not return."""
    fq = np.array([c.freqs[i] for i, _ in ij])
    pr = np.array([c.press[j] for _, j in ij])
    states = sim.steady(dq, fq, pr, grid.output_pressure_pa)
    v = np.array([_clipped(st.value) for st in states])
    for (i, j), dd, vv, st in zip(ij, dq, v, states):
        if not math.isnan(vv):
            c.extra_at(i, j)[float(dd)] = float(vv)
        sim.stats.unconverged += int(not st.converged)
    return v


def _edge_brackets(c: _Curves, stop_tolerance: float
                   ) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray, np.ndarray]:
    """Per curve, the grid bracket of the dead band edge (kind 0) and of the saturation
    edge (kind 1); dead-band brackets first: ``sim.steady`` deals points out to the
    workers alternately, and a closed valve costs a few periods where a moving spool costs
    many, so interleaving the kinds would load one worker with every expensive point."""
    ij: list[tuple[int, int]] = []
    lo_l, hi_l, kind_l = [], [], []
    for i, j in c.indices():
        feat = curve_features(c.duty, c.x[i, j], stop_tolerance)
        if feat.opens and feat.dead_band_duty < feat.opening_duty:
            ij.append((i, j))
            lo_l.append(feat.dead_band_duty)
            hi_l.append(feat.opening_duty)
            kind_l.append(0)
        if not math.isnan(feat.saturation_duty):
            k = int(np.searchsorted(c.duty, feat.saturation_duty))
            if k > 0:
                ij.append((i, j))
                lo_l.append(c.duty[k - 1])
                hi_l.append(c.duty[k])
                kind_l.append(1)
    perm = np.argsort(np.array(kind_l, dtype=int), kind='stable')
    return ([ij[n] for n in perm], np.array(lo_l)[perm], np.array(hi_l)[perm],
            np.array(kind_l, dtype=int)[perm])


def _edges_stage(sim: MapSimulator, grid: MapGrid, c: _Curves, edge_tolerance: float,
                 stop_tolerance: float, progress: ProgressCallback | None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Dead band and saturation edges of every curve by bisection (NaN: the curve has
    none); every bracket of a step runs in one batch."""
    n_f, n_p = c.freqs.size, c.press.size
    db_edges = np.full((n_f, n_p), math.nan)
    sat_edges = np.full((n_f, n_p), math.nan)
    ij, lo_c, hi_c, kind = _edge_brackets(c, stop_tolerance)
    if not ij:
        return db_edges, sat_edges
    step = 0
    # dead band: "hi" = opens; saturation: "hi" = stays open; same batches
    while np.max(hi_c - lo_c) > edge_tolerance:
        mid = np.round(0.5 * (lo_c + hi_c), 6)
        v = _run_extra(sim, grid, c, ij, mid)
        # a point the model never returned for (NaN) counts as "not hi"
        flags = np.where(kind == 0, v > stop_tolerance, v >= 1.0 - stop_tolerance)
        hi_c = np.where(flags, mid, hi_c)
        lo_c = np.where(flags, lo_c, mid)
        step += 1
        if progress:
            progress(grid.n_points, grid.n_points, f'edge bisection step {step}: bracket '
                                                   f'{np.max(hi_c - lo_c):.2%}')
    for n, (i, j) in enumerate(ij):
        (db_edges if kind[n] == 0 else sat_edges)[i, j] = 0.5 * (lo_c[n] + hi_c[n])
    return db_edges, sat_edges


def _refine_stage(sim: MapSimulator, grid: MapGrid, c: _Curves, refinement: Refinement,
                  progress: ProgressCallback | None) -> None:
    """Adaptive refinement: a segment whose midpoint leaves the chord by more than the
    tolerance, or that rises too steeply, is halved, level by level, down to the minimum
    spacing; each level's midpoints run in one batch."""
    segs: list[tuple[int, int, float, float]] = []
    for i, j in c.indices():
        dmap_pts = _merged(c.duty, c.x[i, j], c.extra_at(i, j))
        for a, b in sorted(_initial_segments(*dmap_pts, refinement)):
            segs.append((i, j, a, b))
    level = 0
    while segs and level < refinement.max_levels:
        level += 1
        ij = [(i, j) for i, j, _, _ in segs]
        # midpoints on a 1e-6 duty lattice: short numbers in the file
        mids = np.array([round(0.5 * (a + b), 6) for _, _, a, b in segs])
        v = _run_extra(sim, grid, c, ij, mids)
        nxt = []
        for (i, j, a, b), m, vm in zip(segs, mids, v):
            pts = c.extra_at(i, j)
            va = _value_at(c.duty, c.x[i, j], pts, a)
            vb = _value_at(c.duty, c.x[i, j], pts, b)
            if math.isnan(vm):
                continue
            curved = abs(vm - 0.5 * (va + vb)) > refinement.interp_tolerance
            steep = abs(vb - va) > refinement.max_rise
            if (curved or steep) and 0.5 * (b - a) > refinement.min_spacing * 1.0001:
                m = float(m)
                for c0, c1, w0, w1 in ((a, m, va, vm), (m, b, vm, vb)):
                    if abs(w1 - w0) > refinement.interp_tolerance:
                        nxt.append((i, j, c0, c1))
        segs = nxt
        if progress:
            progress(grid.n_points, grid.n_points,
                     f'adaptive refinement level {level}: {len(mids)} points, '
                     f'{len(segs)} segments left')


def _fill_and_notes(sim: MapSimulator, c: _Curves) -> list[str]:
    """Grid points the model never returned for, interpolated from their neighbours; the
    notes the file carries (these, the workers' incidents, unconverged and sub-harmonic
    points)."""
    stats = sim.stats
    notes: list[str] = []
    for i, j in c.indices():
        bad = np.isnan(c.x[i, j])
        if bad.any():
            c.x[i, j, bad] = np.interp(c.duty[bad], c.duty[~bad], c.x[i, j, ~bad])
            notes.append(f'{int(bad.sum())} grid point(s) at {c.freqs[i]:g} Hz, '
                         f'{c.press[j]:g} Pa interpolated from neighbours (model '
                         'did not return)')
    stats.unconverged += int(np.sum(~c.converged))
    stats.subharmonic = int(np.sum(c.cycles > 1))
    notes += sim.incidents
    if stats.unconverged:
        notes.append(f'{stats.unconverged} simulated point(s) did not meet the steady-state '
                     f'criterion within {sim.criterion.max_periods} periods (value = mean '
                     'over the second half of the periods)')
    if stats.subharmonic:
        notes.append(f'{stats.subharmonic} grid point(s) settled to a sub-harmonic cycle '
                     '(value = average over the whole cycle)')
    return notes


def _generate(sim: MapSimulator, grid: MapGrid, refine_edges: bool, edge_tolerance: float,
              refinement: Refinement | None, stop_tolerance: float,
              progress: ProgressCallback | None, generator: dict | None,
              t_start: float) -> tuple[DutyMap, GenerationStats]:
    """The stages: grid, edges, adaptive refinement, then the map with its provenance."""
    stats = sim.stats
    stats.extra['startup_s'] = time.perf_counter() - t_start
    c = _grid_stage(sim, grid, stop_tolerance, progress)
    t1 = time.perf_counter()
    db_edges = sat_edges = None
    if refine_edges:
        db_edges, sat_edges = _edges_stage(sim, grid, c, edge_tolerance, stop_tolerance,
                                           progress)
    if refinement is not None:
        _refine_stage(sim, grid, c, refinement, progress)
    stats.refine_wall_s = time.perf_counter() - t1
    stats.wall_s = time.perf_counter() - t_start
    notes = _fill_and_notes(sim, c)
    gen = {'program': 'valve_model_pkg.maps.generate_map', 'wall_s': round(stats.wall_s, 3),
           'runs': stats.runs, 'simulated_s': round(stats.simulated_s, 3),
           'threads': stats.threads, 'refine_edges': refine_edges,
           'edge_tolerance': edge_tolerance}
    gen.update(generator or {})
    extra_points = [(np.array(sorted(e)), np.array([e[k] for k in sorted(e)]))
                    for e in c.extra]
    dmap = DutyMap(duty=c.duty, supply_pressures_pa=c.press, pwm_frequencies_hz=c.freqs,
                   position_fraction=c.x, parameters=sim.params.to_dict(),
                   electronics=sim.electronics.to_dict(), supply_voltage_v=sim.supply_voltage_v,
                   output_pressure_pa=grid.output_pressure_pa,
                   steady_state=sim.criterion.as_dict(), periods=c.periods,
                   converged=c.converged, cycles=c.cycles, dead_band_edges=db_edges,
                   saturation_edges=sat_edges, stop_tolerance=stop_tolerance,
                   extra_points=extra_points,
                   refinement=refinement.as_dict() if refinement is not None else {},
                   created_utc=_dt.datetime.now(_dt.timezone.utc).strftime(
                       '%Y-%m-%dT%H:%M:%SZ'),
                   generator=gen, notes=notes)
    return dmap, stats


def _merged(duty: np.ndarray, x: np.ndarray, pts: dict[float, float]
            ) -> tuple[np.ndarray, np.ndarray]:
    d = dict(zip((float(v) for v in duty), (float(v) for v in x)))
    d.update(pts)
    keys = sorted(d)
    return np.array(keys), np.array([d[k] for k in keys])


def _value_at(duty: np.ndarray, x: np.ndarray, pts: dict[float, float], d: float) -> float:
    if d in pts:
        return pts[d]
    k = int(np.argmin(np.abs(duty - d)))
    return float(x[k])
