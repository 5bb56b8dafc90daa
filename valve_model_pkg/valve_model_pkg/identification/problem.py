"""The identification problem: which parameters, within which bounds, against which data.

Section 4 of the paper: Table 1's values (m_s, k, N, A_1..A_4) are measured and known; the
eight parameters of Table 2 are identified by a direct search that minimises the integral
of the absolute error between simulated and measured current, inside physically sensible
ranges around the measured values.

Cost
----
For each file ``f`` the error integral ``IAE_f = int |i_meas - i_sim| dt`` (trapezoid over
the samples that have a current; missing samples are bridged). The cost is
``sum_f IAE_f / T_f``: each file's mean absolute error, so a 2.6 s heating record and a
40 ms step weigh the same whatever their length and sample rate.
"""
from __future__ import annotations

import copy
import math
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence, TypeVar

import numpy as np

from ..model import ElectronicsConfig
from ..model import PARALLEL_MIN_BATCH, batch_threads
from ..model.magnetics import MU_0
from ..model.parameters import EFFECTS, ValveParameters
from ..errors import IdentificationError
from .measurement import Measurement
from .model_adapter import FIELD_INDEX, TraceSetup, prepare_trace, simulate_measurement

__all__ = [
    'IDENTIFIED_FIELDS',
    'TABLE2_MEASURED',
    'ParameterBound',
    'ParameterSpace',
    'FitData',
    'ErrorFigures',
    'baseline_space',
    'effect_space',
]

#: The eight parameters of Table 2 that the identification estimates.
IDENTIFIED_FIELDS: tuple[str, ...] = (
    'core_length_m', 'coil_resistance_ohm', 'stroke_m', 'core_area_m2',
    'spring_pretension_m', 'total_air_gap_m', 'damping_n_s_per_m', 'relative_permeability',
)

#: Table 2's *measured* values (None where the paper has none: b and mu_r).
TABLE2_MEASURED: dict[str, float | None] = {
    'core_length_m': 0.11,
    'coil_resistance_ohm': 15.0,
    'stroke_m': 0.30e-3,
    'core_area_m2': 0.75e-4,
    'spring_pretension_m': 1.1e-3,
    'total_air_gap_m': 0.35e-3,
    'damping_n_s_per_m': None,
    'relative_permeability': None,
}

#: Physically sensible search ranges (SI). Around the measured values: lengths and
#: areas within about -50 % / +60 % (the lumped magnetic model's effective values differ
#: from the geometry, the paper's own identified values lie 5-15 % off), R from a cold
#: 15 ohm down to half and up to hot copper; b and mu_r, never measured, over decades.
_BOUNDS: dict[str, tuple[float, float]] = {
    'core_length_m': (0.05, 0.25),
    'coil_resistance_ohm': (7.5, 22.5),
    'stroke_m': (0.15e-3, 0.45e-3),
    'core_area_m2': (0.4e-4, 1.2e-4),
    'spring_pretension_m': (0.55e-3, 2.0e-3),
    'total_air_gap_m': (0.2e-3, 0.6e-3),
    'damping_n_s_per_m': (0.01, 10.0),
    'relative_permeability': (20.0, 2000.0),
}

#: Smallest holding gap x_t - x_max the search allows [m] (eq. 2: L(x_max) stays finite).
MIN_HOLDING_GAP_M = 5e-6

_GAP_FIELDS = ('core_length_m', 'relative_permeability', 'total_air_gap_m')

PAPER_SYMBOLS = {
    'core_length_m': 'l_c', 'coil_resistance_ohm': 'R', 'stroke_m': 'x_max',
    'core_area_m2': 'A_e', 'spring_pretension_m': 'delta', 'total_air_gap_m': 'x_t',
    'damping_n_s_per_m': 'b', 'relative_permeability': 'mu_r',
    'equivalent_gap_m': 's',
}


@dataclass(frozen=True)
class ParameterBound:
    """One free parameter: its field, search range and scale."""

    name: str
    low: float
    high: float
    log: bool = True

    def to_unit(self, value: float) -> float:
        """Map a physical value into [0, 1] (clipped)."""
        if self.log:
            lo, hi, v = math.log(self.low), math.log(self.high), math.log(max(value, 1e-300))
        else:
            lo, hi, v = self.low, self.high, value
        return min(1.0, max(0.0, (v - lo) / (hi - lo)))

    def from_unit(self, u: np.ndarray) -> np.ndarray:
        """Map unit coordinates to physical values."""
        if self.log:
            return self.low * (self.high / self.low) ** u
        return self.low + (self.high - self.low) * u


#: The search coordinate that replaces l_c, mu_r and x_t (see :class:`ParameterSpace`).
GAP = 'equivalent_gap_m'


def equivalent_gap_m(params: ValveParameters) -> float:
    """``s = l_c / mu_r + 2 x_t`` [m]: the one combination of l_c, mu_r, x_t in eqs. (4)-(8).

    ``L(x) = N^2 A_e mu_0 / (l_c/mu_r + 2 (x_t - x))``, so every current and force of the
    model depends on the three only through ``s``.
    """
    return params.core_length_m / params.relative_permeability + 2.0 * params.total_air_gap_m


@dataclass(frozen=True)
class ParameterSpace:
    """The free parameters of one fit, on top of a fixed base parameter set.

    A bound named :data:`GAP` stands for ``s = l_c/mu_r + 2 x_t``. Eq. (4) contains l_c,
    mu_r and x_t only through ``s``, so no current measurement can tell them apart and a
    search over all three wanders along two flat directions (it slows Nelder-Mead down a
    lot). The search therefore moves ``s``; ``l_c`` and ``x_t`` stay at the measured values
    of Table 2 (``hold``) and ``mu_r = l_c / (s - 2 x_t)``. When the stroke leaves no room
    for the measured x_t, x_t moves half-way into the room that ``s`` leaves.
    """

    base: ValveParameters
    bounds: tuple[ParameterBound, ...]
    hold: tuple[float, float] = (0.11, 0.35e-3)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bounds)

    @property
    def size(self) -> int:
        return len(self.bounds)

    def values_of(self, params: ValveParameters) -> np.ndarray:
        """Physical values of the free parameters, shape (n,)."""
        return np.array([equivalent_gap_m(params) if b.name == GAP
                         else getattr(params, b.name) for b in self.bounds])

    def to_unit(self, params: ValveParameters) -> np.ndarray:
        """Unit coordinates of a parameter set, shape (n,)."""
        return np.array([b.to_unit(v) for b, v in zip(self.bounds, self.values_of(params))])

    def raw_from_values(self, values: np.ndarray) -> np.ndarray:
        """Raw model parameter matrix (m, len(PARAMETER_FIELDS)) from physical values (m, n)."""
        values = np.atleast_2d(values)
        raw = np.repeat(self.base.to_vector()[None, :], values.shape[0], axis=0)
        gap_col = None
        for j, b in enumerate(self.bounds):
            if b.name == GAP:
                gap_col = j
            else:
                raw[:, FIELD_INDEX[b.name]] = values[:, j]
        if gap_col is not None:
            s = values[:, gap_col]
            lc, xt0 = self.hold
            xmax = raw[:, FIELD_INDEX['stroke_m']]
            xt = np.maximum(xt0, xmax + MIN_HOLDING_GAP_M)
            tight = s - 2.0 * xt <= 0.05 * s
            xt = np.where(tight, xmax + 0.5 * (0.5 * s - xmax), xt)
            room = s - 2.0 * xt
            raw[:, FIELD_INDEX['core_length_m']] = lc
            raw[:, FIELD_INDEX['total_air_gap_m']] = xt
            with np.errstate(divide='ignore', invalid='ignore'):
                raw[:, FIELD_INDEX['relative_permeability']] = np.where(
                    room > 0, lc / np.where(room > 0, room, 1.0), np.nan)
        return raw

    def raw_matrix(self, u: np.ndarray) -> np.ndarray:
        """Raw model parameter matrix, shape (m, len(PARAMETER_FIELDS)), from (m, n) units."""
        u = np.atleast_2d(u)
        vals = np.column_stack([b.from_unit(u[:, j]) for j, b in enumerate(self.bounds)])
        return self.raw_from_values(vals)

    def feasible(self, raw: np.ndarray) -> np.ndarray:
        """Rows that describe a valid valve (holding gap open, restitution below 1)."""
        gap = raw[:, FIELD_INDEX['total_air_gap_m']] - raw[:, FIELD_INDEX['stroke_m']]
        ok = gap >= MIN_HOLDING_GAP_M
        mu = raw[:, FIELD_INDEX['relative_permeability']]
        ok &= np.isfinite(mu) & (mu > 1.0) & (mu < 1e6)
        ok &= raw[:, FIELD_INDEX['restitution_coefficient']] < 0.95
        return ok

    def params(self, u: np.ndarray) -> ValveParameters:
        """The ValveParameters of one unit-coordinate point."""
        return ValveParameters.from_vector(self.raw_matrix(u)[0])


def baseline_space(base: ValveParameters) -> ParameterSpace:
    """The paper's eight parameters as six search coordinates (see :class:`ParameterSpace`).

    R, x_max, A_e, delta and b directly; ``s = l_c/mu_r + 2 x_t`` for the other three,
    bounded by what their own ranges allow. Bounds widen if ``base`` lies outside them.
    """
    out = []
    for name in IDENTIFIED_FIELDS:
        if name in _GAP_FIELDS:
            continue
        lo, hi = _BOUNDS[name]
        v = getattr(base, name)
        out.append(ParameterBound(name, min(lo, 0.7 * v), max(hi, 1.4 * v)))
    lc_lo, lc_hi = _BOUNDS['core_length_m']
    mu_lo, mu_hi = _BOUNDS['relative_permeability']
    xt_lo, xt_hi = _BOUNDS['total_air_gap_m']
    s_base = equivalent_gap_m(base)
    out.append(ParameterBound(GAP, min(lc_lo / mu_hi + 2 * xt_lo, 0.7 * s_base),
                              max(lc_hi / mu_lo + 2 * xt_hi, 1.4 * s_base)))
    hold = (float(TABLE2_MEASURED['core_length_m']), float(TABLE2_MEASURED['total_air_gap_m']))
    return ParameterSpace(base, tuple(out), hold)


def start_point(space: ParameterSpace) -> ValveParameters:
    """Table 2's measured values; b and mu_r (never measured) at the middle of their range."""
    changes = {}
    for name, measured in TABLE2_MEASURED.items():
        if measured is None:
            lo, hi = _BOUNDS[name]
            measured = math.sqrt(lo * hi)
        changes[name] = measured
    return space.base.replace(**changes)


def effect_space(space: ParameterSpace, effect: str,
                 at: ValveParameters | None = None) -> ParameterSpace:
    """``space`` plus the parameters of one effect (bounds from the model's registry).

    With ``at``, an upper bound below ``at``'s value of the field (a refit widened it:
    :func:`~.diagnosis.widen_at_bound`) rises to that value, so the point stays inside.
    """
    spec = EFFECTS[effect]
    extra = []
    for name in spec.fields:
        lo, hi = spec.bounds[name]
        if at is not None:
            hi = max(hi, float(getattr(at, name)))
        # Effects switched off at 0 are searched linearly from 0 (log cannot reach it).
        extra.append(ParameterBound(name, lo, hi, log=lo > 0.0))
    return ParameterSpace(space.base, space.bounds + tuple(extra), space.hold)


def with_upper_bound(space: ParameterSpace, name: str, high: float) -> ParameterSpace:
    """``space`` with the upper search bound of ``name`` moved to ``high``."""
    bounds = tuple(replace(b, high=high) if b.name == name else b for b in space.bounds)
    return ParameterSpace(space.base, bounds, space.hold)


@dataclass(frozen=True)
class AmountLimit:
    """The physical upper limit of an effect's amount, beyond which its search bound is
    never widened (:func:`amount_limit`).

    Attributes
    ----------
    value : float
        The limit, in the field's unit.
    why : str
        What the limit is, in words.
    """

    value: float
    why: str


def amount_limit(name: str, params: ValveParameters) -> AmountLimit | None:
    """The physical limit of an effect amount ``name`` for the valve ``params``; None for
    the amounts whose registry bound is already the limit (restitution below 1, copper
    heating, saturation), which are never widened.

    Coulomb friction stays below the spring's closing force ``k delta`` (beyond it the
    spool cannot return to its seat); a leakage inductance below the coil's own inductance
    at the open gap, ``L(0) = N^2 mu_0 A_e / s`` (eq. 4); an eddy-loss conductance below the
    coil's own, ``1/R`` (a lumped loss path that shunts more current than the winding no
    longer describes eddy currents).
    """
    if name == 'coulomb_friction_n':
        return AmountLimit(params.spring_stiffness_n_per_m * params.spring_pretension_m,
                           "the spring's closing force k delta")
    if name == 'leakage_inductance_h':
        l0 = params.coil_turns ** 2 * MU_0 * params.core_area_m2 / equivalent_gap_m(params)
        return AmountLimit(l0, "the coil's inductance at the open gap L(0)")
    if name == 'eddy_conductance_s':
        return AmountLimit(1.0 / params.coil_resistance_ohm, "the coil's conductance 1/R")
    return None


@dataclass(frozen=True)
class ErrorFigures:
    """Error of a simulated current against the measurement.

    Attributes
    ----------
    iae : float
        Integral of the absolute error, summed over the files [A s].
    rmse : float
        Root mean square error over all samples with a current [A].
    nrmse_pct : float
        ``rmse`` relative to the measured current's range (max - min over the files) [%].
    mae_per_file : dict
        Mean absolute error of each file [A] (the cost's terms).
    """

    iae: float
    rmse: float
    nrmse_pct: float
    mae_per_file: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        return {'iae': self.iae, 'rmse': self.rmse, 'nrmse_pct': self.nrmse_pct,
                'mae_per_file_a': self.mae_per_file}


#: Parameter sets whose residuals :meth:`FitData.residuals` keeps.
RESIDUAL_CACHE = 32
#: Smallest batch :meth:`FitData.cost` splits over threads.
_SPLIT_MIN_BATCH = 2
_POOL: list[ThreadPoolExecutor] = []


def _pool() -> ThreadPoolExecutor:
    """The identification's thread pool for small batches (created on first use)."""
    if not _POOL:
        # the kernel's batch threads when first used: NUMBA_NUM_THREADS and the CPUs this
        # process may run on (a fleet worker limited to one thread keeps to it)
        _POOL.append(ThreadPoolExecutor(max_workers=batch_threads(),
                                        thread_name_prefix='valve-ident'))
    return _POOL[0]


def _trapezoid_weights(t: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Weights w with sum(w |r|) = trapezoid integral of |r| over the valid samples."""
    w = np.zeros(t.size)
    tv = t[valid]
    if tv.size < 2:
        return w
    dt = np.diff(tv)
    wv = np.zeros(tv.size)
    wv[:-1] += 0.5 * dt
    wv[1:] += 0.5 * dt
    w[valid] = wv
    return w


#: Multi-second records are compared at this rate at most: their information is the slow
#: drift (coil heating), and the simulation cost grows with the number of output samples.
LONG_RECORD_S = 0.5
LONG_RECORD_RATE_HZ = 1000.0


#: The search stages compare fast step records at this rate at most (:func:`coarse_data`):
#: the kernel's cost grows with the output samples (a 40 ms step at 50 kHz costs 2.5 times
#: its run at 10 kHz). The stroke's dip and the rise (time constants of 1 ms and more) are
#: drawn by every 100 us, but on noise-free steps the baseline's valley is flat enough
#: that a search on 10 kHz data settles where the hold-out misses by 1.4 mA against
#: 0.45 mA at 20 kHz: 20 kHz keeps the first 100 us of the rise in the search. The
#: polishes, criteria and selection compare every sample.
SEARCH_RATE_HZ = 20000.0


def _every_kth(m: Measurement, rate_hz: float) -> np.ndarray:
    """Samples of every k-th of ``m``'s sample periods, k = its rate over ``rate_hz``."""
    k = int(m.sample_rate_hz // rate_hz)
    n = np.round((m.t_s - m.t_s[0]) * m.sample_rate_hz).astype(np.int64)
    return n % k == 0


def _search_decimation(m: Measurement, rate_hz: float) -> np.ndarray | None:
    """Samples a search compares of a step record faster than ``rate_hz`` (None: all, or
    as :func:`_decimation` keeps them)."""
    if m.drive is not None or m.voltage_hold == 'interval_mean' or m.sampling != 'instant':
        return None
    if _decimation(m) is not None or m.sample_rate_hz <= 1.2 * rate_hz:
        return None
    return _every_kth(m, rate_hz)


def _decimation(m: Measurement) -> np.ndarray | None:
    """Samples kept for fitting: all, or every k-th of a long, fast record."""
    if m.sampling == 'interval_mean' and (m.drive is not None
                                          or m.voltage_hold == 'interval_mean'):
        return None  # interval means are compared over the record's own intervals
    if m.duration_s < LONG_RECORD_S or m.sample_rate_hz <= 1.2 * LONG_RECORD_RATE_HZ:
        return None
    return _every_kth(m, LONG_RECORD_RATE_HZ)


def _subset(m: Measurement, keep: np.ndarray) -> Measurement:
    """The kept samples of ``m`` as a Measurement of their own (for errors and plots)."""
    from dataclasses import replace
    note = (f'compared at {keep.sum()} of {keep.size} samples (every '
            f'{int(round(keep.size / keep.sum()))}th): a long record is fitted on its drift')
    return replace(m.samples(keep), notes=m.notes + (note,))


class FitData:
    """A set of measurements prepared for fast batch cost evaluation.

    Parameters
    ----------
    measurements : sequence of Measurement
        Fit or validation files.
    max_rate_hz : float, optional
        Compare step records faster than this at every k-th sample only (the searches'
        data, :func:`coarse_data`); long records are compared at
        :data:`LONG_RECORD_RATE_HZ` either way.
    """

    def __init__(self, measurements: Sequence[Measurement],
                 max_rate_hz: float | None = None) -> None:
        if not measurements:
            raise IdentificationError('no measurement given')
        self.full = list(measurements)
        self.max_rate_hz = max_rate_hz
        self.measurements = []
        self.setups: list[TraceSetup] = []
        for m in self.full:
            keep = _decimation(m)
            if keep is None and max_rate_hz is not None:
                keep = _search_decimation(m, max_rate_hz)
            self.setups.append(prepare_trace(m, keep=keep))
            self.measurements.append(m if keep is None else _subset(m, keep))
        self.valid = [m.valid for m in self.measurements]
        if not any(v.sum() >= 10 for v in self.valid):
            raise IdentificationError('fewer than 10 samples left to compare after the '
                                      'discarded start of the records')
        self.weights = [_trapezoid_weights(m.t_s, v)
                        for m, v in zip(self.measurements, self.valid)]
        self.durations = [float(w.sum()) for w in self.weights]
        self._count = [0]  # shared with serial() views, so threads' runs are counted too
        #: False keeps every batch on the calling thread (see :meth:`serial`).
        self.parallel = True
        #: Threads a small batch is split over (:meth:`cost`) and the drive electronics'
        #: candidates run on.
        self.workers = batch_threads()
        #: Drive electronics of the records through the electronics (identified
        #: separately, :mod:`.drive`); the same for every run of a batch.
        self.electronics = ElectronicsConfig()
        # The residuals of the last parameter sets asked for (shared with serial()
        # views): the stages after the search ask for the same models' residuals again
        # (errors, noise, effective sample counts, structure), and a run is dear.
        self._residuals: OrderedDict[tuple, list[np.ndarray]] = OrderedDict()
        self._lock = threading.Lock()
        #: Main PWM grid placements of parameter sets (:func:`.phase.phase_shifts`;
        #: shared with serial() views).
        self.phase_cache: dict[tuple, tuple[float, ...]] = {}
        #: Searches of the drive electronics' constants with the valve held (:mod:`.drive`),
        #: by their arguments (shared with serial() views): the form choice asks for the
        #: same search again from several of its stages, and each costs hundreds of runs.
        self.drive_cache: dict[tuple, object] = {}

    @property
    def through_electronics(self) -> bool:
        """True when any file runs the drive electronics."""
        return any(s.drive is not None for s in self.setups)

    @property
    def simulations(self) -> int:
        """Simulations run on this data (views included)."""
        return self._count[0]

    def serial(self) -> 'FitData':
        """A view on the same data whose simulations stay on the calling thread.

        For running several searches in Python threads at once (see
        :func:`model_adapter.simulate_measurement`).
        """
        view = copy.copy(self)
        view.parallel = False
        return view

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.measurements]

    def simulate(self, raw: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Simulated (current, position) of each file, each of shape (m, n_samples)."""
        raw = np.atleast_2d(raw)
        self._count[0] += raw.shape[0] * len(self.setups)
        return [simulate_measurement(raw, s, parallel=self.parallel,
                                     electronics=self.electronics) for s in self.setups]

    def at_bound(self, space: 'ParameterSpace', params: ValveParameters,
                 fraction: float = 0.01) -> list[str]:
        """Free parameters of ``space`` within ``fraction`` of their range from a bound."""
        u = space.to_unit(params)
        return [n for n, x in zip(space.names, u) if x <= fraction or x >= 1.0 - fraction]

    def cost(self, raw: np.ndarray) -> np.ndarray:
        """Sum over files of the mean absolute current error [A], shape (m,)."""
        raw = np.atleast_2d(raw)
        m_rows = raw.shape[0]
        if self.parallel and _SPLIT_MIN_BATCH <= m_rows < PARALLEL_MIN_BATCH and self.workers > 1:
            # The kernel runs batches below PARALLEL_MIN_BATCH on the calling thread (the
            # lock-step Nelder-Mead asks 2-7 points at a time): split them over threads,
            # each simulating without the GIL, so both cores work.
            view = self.serial()
            parts = np.array_split(raw, min(self.workers, m_rows))
            return np.concatenate(list(_pool().map(view.cost, parts)))
        total = np.zeros(raw.shape[0])
        for m, setup, w, T in zip(self.measurements, self.setups, self.weights,
                                  self.durations):
            cur, _ = simulate_measurement(raw, setup, parallel=self.parallel,
                                          electronics=self.electronics)
            err = np.abs(np.where(np.isfinite(m.current_a), m.current_a, 0.0)[None, :] - cur)
            err[~np.isfinite(err)] = np.inf
            total += err @ w / T
        self._count[0] += raw.shape[0] * len(self.setups)
        return np.where(np.isfinite(total), total, np.inf)

    def residuals(self, params: ValveParameters) -> list[np.ndarray]:
        """Measured minus simulated current of each file [A] (nan where not measured).

        The last :data:`RESIDUAL_CACHE` parameter sets' residuals (under the electronics in
        force) are kept and handed out again (read-only arrays)."""
        raw = params.to_vector()
        key = (raw.tobytes(), self.electronics)
        with self._lock:
            hit = self._residuals.get(key)
            if hit is not None:
                self._residuals.move_to_end(key)
                return list(hit)
        sims = self.simulate(raw[None, :])
        out = [np.where(v, m.current_a - c[0], np.nan)
               for m, v, (c, _) in zip(self.measurements, self.valid, sims)]
        for r in out:
            r.setflags(write=False)
        with self._lock:
            self._residuals[key] = out
            while len(self._residuals) > RESIDUAL_CACHE:
                self._residuals.popitem(last=False)
        return list(out)

    def errors(self, params: ValveParameters) -> ErrorFigures:
        """IAE, RMSE and NRMSE of ``params`` on these files."""
        res = self.residuals(params)
        iae = 0.0
        sq = 0.0
        n = 0
        mae = {}
        lo, hi = math.inf, -math.inf
        for m, r, w, T, v in zip(self.measurements, res, self.weights, self.durations,
                                 self.valid):
            a = np.abs(np.where(v, r, 0.0))
            iae_f = float(a @ w)
            iae += iae_f
            mae[m.name] = iae_f / T if T > 0 else math.nan
            sq += float(np.sum(r[v] ** 2))
            n += int(v.sum())
            lo = min(lo, float(np.min(m.current_a[v])))
            hi = max(hi, float(np.max(m.current_a[v])))
        rmse = math.sqrt(sq / n) if n else math.nan
        span = hi - lo
        return ErrorFigures(iae=iae, rmse=rmse,
                            nrmse_pct=100.0 * rmse / span if span > 0 else math.nan,
                            mae_per_file=mae)


def coarse_data(data: FitData, rate_hz: float = SEARCH_RATE_HZ) -> FitData:
    """``data`` with its step records faster than ``rate_hz`` compared at every k-th sample
    (the searches' data; the same threads and electronics), or ``data`` itself when no
    record is that fast."""
    if all(_search_decimation(m, rate_hz) is None for m in data.full):
        return data
    out = FitData(data.full, max_rate_hz=rate_hz)
    out.parallel, out.workers, out.electronics = data.parallel, data.workers, data.electronics
    return out


def unit_objective(space: ParameterSpace, data: FitData):
    """Batch objective over unit coordinates for :func:`search.direct_search`."""
    def fun(u: np.ndarray) -> np.ndarray:
        raw = space.raw_matrix(u)
        ok = space.feasible(raw)
        out = np.full(raw.shape[0], np.inf)
        if ok.any():
            out[ok] = data.cost(raw[ok])
        return out
    return fun


_T = TypeVar('_T')


def remembered(cache: dict, key: object, compute: Callable[[], _T], limit: int) -> _T:
    """``compute()``'s result, kept in ``cache`` (a dict a :class:`FitData` shares with
    its serial views) under ``key`` and handed out again; beyond ``limit`` entries the
    oldest goes. For deterministic work only: the same key must give the same result."""
    if key in cache:
        return cache[key]
    out = compute()
    cache[key] = out
    while len(cache) > limit:
        cache.pop(next(iter(cache)))
    return out


__all__ += ['AmountLimit', 'GAP', 'MIN_HOLDING_GAP_M', 'PAPER_SYMBOLS', 'SEARCH_RATE_HZ',
            'amount_limit', 'coarse_data', 'equivalent_gap_m', 'with_upper_bound',
            'remembered', 'start_point', 'unit_objective']
