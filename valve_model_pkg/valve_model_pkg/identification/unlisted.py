"""An effect outside the list: a sparse term in the voltage balance, chosen on hold-out data.

When no listed effect pays for its parameters and the baseline residual still holds
structure (:func:`.diagnosis.select` answers ``none`` with ``unexplained_structure``), this
module offers an open-ended augmentation, the SINDy idea (Brunton, Proctor & Kutz 2016)
with a hand-written sequentially thresholded least squares (STLSQ, numpy only):

* **Equation.** The electrical equation gains an unknown voltage drop that is a sparse
  combination of candidate terms::

      V = R i + d(lambda(i, x))/dt + sum_k xi_k theta_k(i, x, v, di/dt, V)

  with the library :data:`LIBRARY` (1, i, i^2, i^3, i|i|, tanh(i / 0.1 A), x, v, x i,
  v i, di/dt, V), evaluated on the baseline simulation (its current, spool position and
  velocity, the current's slope) and the record's voltage.
* **Current, not voltage.** The records measure the current; differentiating a noisy
  current for the voltage balance amplifies the noise by the sample rate. The term's effect
  on the current is therefore computed instead, linearised along the baseline trajectory
  with the spool motion held: ``L(x) d(di)/dt + (R + L'(x) v) di = -theta_k``, integrated
  exactly per sample interval (coefficients held). The current residual (measured minus
  baseline) is then regressed on these responses, so the coefficients ``xi_k`` are those
  of the voltage balance, in V per unit of each term, and the augmented current is the
  baseline's plus ``sum_k xi_k di_k``. The spool motion's reaction to the changed current
  is neglected (stated in the report; it shows as larger errors around the strokes).
* **Baseline parameters move with the term**, as a listed candidate's refit moves them:
  the STLSQ path is computed with the baseline's current Jacobian projected out; each
  support's joint least-squares step is applied to the baseline parameters and simulated
  by the kernel, and the term's coefficients are refitted along that new trajectory.
* **Sparse path.** Columns normalised, ridge-regularised least squares, coefficients below
  a threshold set to zero and the rest refitted, repeated until the support settles; a
  grid of thresholds gives a path of supports of at most :data:`MAX_TERMS` terms, each
  refitted by plain least squares on its support (the fit data only).
* **Selection, on the hold-out data, with the listed candidates' two criteria**
  (:mod:`.diagnosis`): dBIC on the fit data below ``DBIC_THRESHOLD`` and on the validation
  data below it too, with the validation mean absolute error falling by at least
  ``MIN_VALIDATION_GAIN``; each term counts as a parameter. Among the supports that pass,
  the one with the lowest validation dBIC wins (the threshold is thus cross-validated on
  the hold-out data). Confidence is ``medium`` if it also removes at least half of the
  validation residual's energy beyond the noise, else ``low``; never high, and a listed
  effect's name is never given to it.

The kernel has no such term, so ``params.yaml`` cannot carry it: the terms and
coefficients go to ``report.json`` under ``unlisted`` and the augmented model's parameters
stay the baseline's. Records through the drive electronics are not offered this search
(the chopper regulates the current, so an extra voltage does not show in it as the
linearised bare-coil response says); neither is a baseline with parameters at a search
bound that the data determine (its misfit is not read as a missing effect).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..model.magnetics import inductance, inductance_slope
from ..model.parameters import ValveParameters
from .criteria import (DBIC_THRESHOLD, MIN_EXPLAINED, MIN_VALIDATION_GAIN, delta_bic,
                       effective_counts, noise_per_file, resolution_floors, structured_energy_of)
from .diagnosis import Diagnosis
from .problem import IDENTIFIED_FIELDS, FitData, ParameterSpace, baseline_space
from .sensitivity import file_jacobians

__all__ = ['LIBRARY', 'MAX_TERMS', 'SparseModel', 'UnlistedResult', 'library',
           'responses', 'stlsq_path', 'search_unlisted', 'offer_unlisted']

#: Current scale of the tanh term [A]: a soft sign (a diode-like drop) that saturates
#: well below the holding current.
TANH_SCALE_A = 0.1
#: Candidate terms: name -> (unit of the term, function of the trajectory).
LIBRARY: dict[str, tuple[str, Callable[[dict], np.ndarray]]] = {
    '1': ('1', lambda s: np.ones_like(s['i'])),
    'i': ('A', lambda s: s['i']),
    'i^2': ('A^2', lambda s: s['i'] ** 2),
    'i^3': ('A^3', lambda s: s['i'] ** 3),
    'i|i|': ('A^2', lambda s: s['i'] * np.abs(s['i'])),
    f'tanh(i/{TANH_SCALE_A:g} A)': ('1', lambda s: np.tanh(s['i'] / TANH_SCALE_A)),
    'x': ('m', lambda s: s['x']),
    'v': ('m/s', lambda s: s['v']),
    'x*i': ('m A', lambda s: s['x'] * s['i']),
    'v*i': ('m/s A', lambda s: s['v'] * s['i']),
    'di/dt': ('A/s', lambda s: s['didt']),
    'V': ('V', lambda s: s['V']),
}
#: Largest number of terms a sparse model may hold (parsimony; the BIC pays per term).
MAX_TERMS = 4
#: Thresholds of the STLSQ path, on the coefficients of unit-norm columns, relative to the
#: largest such coefficient of the full least-squares fit.
_THRESHOLDS = np.geomspace(0.02, 0.9, 24)
#: Ridge regularisation of STLSQ relative to the normalised Gram matrix's scale.
_RIDGE = 1e-6
_STLSQ_ITERATIONS = 10


def _trajectory(m: object, current: np.ndarray, position: np.ndarray) -> dict:
    """Baseline trajectory of one file: i, x, v, di/dt, V on the file's samples."""
    t = m.t_s
    # Velocities and slopes from the simulation (smooth), on the file's own times.
    v = np.gradient(position, t) if t.size > 1 else np.zeros_like(t)
    didt = np.gradient(current, t) if t.size > 1 else np.zeros_like(t)
    return {'t': t, 'i': current, 'x': position, 'v': v, 'didt': didt,
            'V': np.asarray(m.voltage_v, dtype=float)}


def library(traj: dict, names: list[str] | None = None) -> np.ndarray:
    """Library columns evaluated on one trajectory, shape (n_samples, n_terms)."""
    names = list(LIBRARY) if names is None else names
    return np.column_stack([LIBRARY[n][1](traj) for n in names])


def responses(params: ValveParameters, traj: dict, theta: np.ndarray) -> np.ndarray:
    """Current response to each library term added to the voltage balance [A per unit].

    Solves ``L(x) dy/dt + (R + L'(x) v) y = -theta`` from ``y = 0`` along the baseline
    trajectory, the coefficients held over each sample interval (exact exponential step).

    Returns
    -------
    numpy.ndarray, shape like ``theta``
    """
    t = traj['t']
    L = np.asarray(inductance(params, traj['x']), dtype=float)
    dL = np.asarray(inductance_slope(params, traj['x']), dtype=float)
    a = (params.coil_resistance_ohm + dL * traj['v']) / L
    # Guard against a non-positive rate (a fast closing stroke): keep the decay physical.
    a = np.maximum(a, 1e-3 * params.coil_resistance_ohm / L)
    h = np.diff(t)
    decay = np.exp(-a[:-1] * h)
    gain = -(1.0 - decay) / (a[:-1] * L[:-1])
    y = np.zeros_like(theta)
    for k in range(t.size - 1):
        y[k + 1] = y[k] * decay[k] + gain[k] * theta[k]
    return y


@dataclass
class SparseModel:
    """One support of the STLSQ path, refitted on the fit data."""

    terms: list[str]
    coefficients: dict[str, float]
    fit_mae: dict[str, float] = field(default_factory=dict)
    val_mae: dict[str, float] = field(default_factory=dict)
    dbic_fit: float = math.nan
    dbic_val: float = math.nan
    fit_gain: float = math.nan
    val_gain: float = math.nan
    passes: bool = False
    reason: str = ''

    def to_json(self) -> dict[str, object]:
        def f(x: float) -> float | None:
            return x if math.isfinite(x) else None
        return {'terms': self.terms, 'coefficients': self.coefficients,
                'delta_bic_fit': f(self.dbic_fit), 'delta_bic_validation': f(self.dbic_val),
                'fit_error_reduction_pct': f(100 * self.fit_gain),
                'validation_error_reduction_pct': f(100 * self.val_gain),
                'passes': self.passes, 'reason': self.reason}


def stlsq_path(A: np.ndarray, b: np.ndarray, max_terms: int = MAX_TERMS
               ) -> list[tuple[int, ...]]:
    """Supports of sequentially thresholded ridge least squares over a threshold grid.

    Parameters
    ----------
    A : numpy.ndarray, shape (n, p)
        Regressors (columns are normalised here).
    b : numpy.ndarray, shape (n,)
        Target.
    max_terms : int
        Supports larger than this are dropped.

    Returns
    -------
    list of tuple of int
        Distinct non-empty supports, smallest first.
    """
    norms = np.linalg.norm(A, axis=0)
    usable = norms > 0
    An = np.where(usable, A / np.where(usable, norms, 1.0), 0.0)
    gram = An.T @ An
    ridge = _RIDGE * max(float(np.trace(gram)) / max(gram.shape[0], 1), 1e-30)

    def solve(cols: np.ndarray) -> np.ndarray:
        g = gram[np.ix_(cols, cols)] + ridge * np.eye(cols.size)
        return np.linalg.solve(g, An[:, cols].T @ b)

    full = np.flatnonzero(usable)
    if full.size == 0:
        return []
    c_full = np.zeros(A.shape[1])
    c_full[full] = solve(full)
    scale = float(np.max(np.abs(c_full)))
    supports: set[tuple[int, ...]] = set()
    for thr in _THRESHOLDS * scale:
        support = full.copy()
        coef = c_full.copy()
        for _ in range(_STLSQ_ITERATIONS):
            keep = support[np.abs(coef[support]) >= thr]
            if keep.size == 0 or np.array_equal(keep, support):
                support = keep
                break
            support = keep
            coef = np.zeros(A.shape[1])
            coef[support] = solve(support)
        if 0 < support.size <= max_terms:
            supports.add(tuple(int(k) for k in support))
    # Every single term as well: the one-term models are the most parsimonious offers.
    for k in full:
        supports.add((int(k),))
    return sorted(supports, key=lambda s: (len(s), s))


@dataclass
class UnlistedResult:
    """Outcome of :func:`search_unlisted` (report.json ``unlisted``)."""

    tried: bool
    claimed: bool
    reason: str
    equation: str = ''
    model: SparseModel | None = None
    path: list[SparseModel] = field(default_factory=list)
    errors: dict[str, dict[str, float | None]] = field(default_factory=dict)
    structure_explained: float = math.nan
    confidence: str = 'low'
    #: Augmented current of each file (fit, validation), for the plots.
    currents: dict[str, list[np.ndarray]] = field(default_factory=dict)
    #: The baseline parameters as moved with the term (its joint step).
    baseline_parameters: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, object]:
        m = self.model
        return {
            'tried': self.tried, 'claimed': self.claimed, 'reason': self.reason,
            'equation': self.equation,
            'library': {n: u for n, (u, _) in LIBRARY.items()},
            'terms': m.terms if m else [],
            'coefficients': m.coefficients if m else {},
            'coefficient_units': {n: _unit(n) for n in (m.terms if m else [])},
            'delta_bic_fit': m.dbic_fit if m else None,
            'delta_bic_validation': m.dbic_val if m else None,
            'errors': self.errors,
            'structure_explained_pct': 100 * self.structure_explained
            if math.isfinite(self.structure_explained) else None,
            'confidence': self.confidence if self.claimed else None,
            'in_params_yaml': False,
            'baseline_parameters_with_term': self.baseline_parameters,
            'path': [p.to_json() for p in self.path],
            'rule': (f'STLSQ supports of at most {MAX_TERMS} terms fitted on the fit data; '
                     f'kept if dBIC(fit) < {DBIC_THRESHOLD:g} and dBIC(validation) < '
                     f'{DBIC_THRESHOLD:g} and validation MAE falls >= '
                     f'{100 * MIN_VALIDATION_GAIN:g} % (each term one parameter); the '
                     'lowest validation dBIC wins'),
        }


@dataclass
class _Simulated:
    """Per file: the model's residual and the library's current responses."""

    residual: list[np.ndarray]
    responses: list[np.ndarray]


def _simulate(data: FitData, raw: np.ndarray, names: list[str]) -> _Simulated:
    """Residual of the model ``raw`` and the current responses of the terms ``names``."""
    params = ValveParameters.from_vector(raw)
    sims = data.simulate(raw[None, :])
    res, cols = [], []
    for m, v, (c, x) in zip(data.measurements, data.valid, sims):
        cur, pos = c[0], x[0]
        traj = _trajectory(m, cur, pos)
        res.append(np.where(v, m.current_a - cur, np.nan))
        cols.append(responses(params, traj, library(traj, names)))
    return _Simulated(res, cols)


def _project_out(J: np.ndarray, A: np.ndarray, b: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``A`` and ``b`` with the span of ``J`` removed (Frisch-Waugh: the library's
    coefficients of a joint least squares with the baseline parameters)."""
    u, sv, _ = np.linalg.svd(J, full_matrices=False)
    keep = sv > 1e-6 * (sv[0] if sv.size else 0.0)
    U = u[:, keep]
    return A - U @ (U.T @ A), b - U @ (U.T @ b)


def _mae(data: FitData, res: list[np.ndarray]) -> dict[str, float]:
    """Mean absolute error of each file (as :meth:`FitData.errors`) [A]."""
    out = {}
    for m, r, w, T, v in zip(data.measurements, res, data.weights, data.durations,
                             data.valid):
        a = np.abs(np.where(v, r, 0.0))
        out[m.name] = float(a @ w) / T if T > 0 else math.nan
    return out


def _figures(data: FitData, res: list[np.ndarray]) -> dict[str, float | None]:
    mae = _mae(data, res)
    sq = sum(float(np.sum(r[v] ** 2)) for r, v in zip(res, data.valid))
    n = sum(int(v.sum()) for v in data.valid)
    iae = sum(mae[m.name] * T for m, T in zip(data.measurements, data.durations))
    lo = min(float(np.min(m.current_a[v])) for m, v in zip(data.measurements, data.valid))
    hi = max(float(np.max(m.current_a[v])) for m, v in zip(data.measurements, data.valid))
    rmse = math.sqrt(sq / n) if n else math.nan
    return {'iae': iae, 'rmse': rmse,
            'nrmse_pct': 100 * rmse / (hi - lo) if hi > lo else None}


def _stack(data: FitData, arrays: list[np.ndarray]) -> np.ndarray:
    """Valid samples of every file, each file weighted as in the cost (file means)."""
    out = []
    for a, w, T, v in zip(arrays, data.weights, data.durations, data.valid):
        s = np.sqrt(w[v] / T)
        out.append(a[v] * (s[:, None] if a.ndim == 2 else s))
    return np.concatenate(out)


def _apply(sim: _Simulated, coef: np.ndarray, columns: list[int]) -> list[np.ndarray]:
    """Residuals after the term: measured - (model + sum xi_k response_k)."""
    return [r - c[:, columns] @ coef for r, c in zip(sim.residual, sim.responses)]


#: Largest change of a baseline parameter the joint (linearised) step may make, in ln.
_MAX_LOG_STEP = 0.5


@dataclass
class _Evaluated:
    """One support's augmented model: the moved baseline parameters (raw vector), the
    term's coefficients, and its simulations on the fit and validation data."""

    raw: np.ndarray
    coef: np.ndarray
    fit: _Simulated
    val: _Simulated


def _evaluate(space: ParameterSpace, fit: FitData, val: FitData, params: ValveParameters,
              names: list[str], support: tuple[int, ...], dlog: np.ndarray
              ) -> _Evaluated | None:
    """The augmented model of one support, simulated: baseline parameters moved by
    ``dlog`` (the kernel), the term's coefficients refitted on the fit data along the new
    trajectory. None when the moved parameters are infeasible."""
    vals = space.values_of(params) * np.exp(np.clip(dlog, -_MAX_LOG_STEP, _MAX_LOG_STEP))
    raw = space.raw_from_values(vals[None, :])
    if not space.feasible(raw)[0]:
        return None
    raw = raw[0]
    sim_f = _simulate(fit, raw, names)
    sim_v = _simulate(val, raw, names)
    cols = list(support)
    A = _stack(fit, [c[:, cols] for c in sim_f.responses])
    b = _stack(fit, [np.where(np.isfinite(r), r, 0.0) for r in sim_f.residual])
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    return _Evaluated(raw, coef, sim_f, sim_v)


@dataclass
class _Reference:
    """The baseline on the fit and validation data, as the supports are judged."""

    fit: FitData
    val: FitData
    res_f: list[np.ndarray]
    res_v: list[np.ndarray]
    counts_f: dict[str, float]
    counts_v: dict[str, float]
    floors_f: dict[str, float]
    floors_v: dict[str, float]
    mae_f: dict[str, float]
    mae_v: dict[str, float]


@dataclass
class _Offer:
    """A judged support: its model and what it leaves (residuals after the term)."""

    model: SparseModel
    raw: np.ndarray
    after_f: list[np.ndarray]
    after_v: list[np.ndarray]


def _judge_support(support: tuple[int, ...], ev: _Evaluated, names: list[str],
                   ref: _Reference) -> _Offer:
    """Errors, dBICs and the keep rule (:mod:`.criteria`) of one evaluated support."""
    m = SparseModel([names[k] for k in support],
                    {names[k]: float(c) for k, c in zip(support, ev.coef)})
    after_f = _apply(ev.fit, ev.coef, list(support))
    after_v = _apply(ev.val, ev.coef, list(support))
    m.fit_mae, m.val_mae = _mae(ref.fit, after_f), _mae(ref.val, after_v)
    p = len(support)
    m.dbic_fit = delta_bic(ref.mae_f, m.fit_mae, ref.counts_f, p, ref.floors_f)
    m.dbic_val = delta_bic(ref.mae_v, m.val_mae, ref.counts_v, p, ref.floors_v)
    m.fit_gain = 1.0 - sum(m.fit_mae.values()) / sum(ref.mae_f.values())
    m.val_gain = 1.0 - sum(m.val_mae.values()) / sum(ref.mae_v.values())
    why = []
    if not m.dbic_fit < DBIC_THRESHOLD:
        why.append(f'fit dBIC {m.dbic_fit:.1f} not below {DBIC_THRESHOLD:g}')
    if not m.dbic_val < DBIC_THRESHOLD:
        why.append(f'validation dBIC {m.dbic_val:.1f} not below {DBIC_THRESHOLD:g}')
    if m.val_gain < 0.0:
        why.append(f'validation error rises ({1e3 * sum(ref.mae_v.values()):.3g} -> '
                   f'{1e3 * sum(m.val_mae.values()):.3g} mA mean absolute error)')
    elif not m.val_gain >= MIN_VALIDATION_GAIN:
        why.append(f'validation error falls {100 * m.val_gain:.2f} %, less than '
                   f'{100 * MIN_VALIDATION_GAIN:g} %')
    m.passes = not why
    m.reason = 'pays for its terms on fit and validation data' if m.passes else \
        '; '.join(why)
    return _Offer(m, ev.raw, after_f, after_v)


def _describe_pick(out: UnlistedResult, pick: _Offer, ref: _Reference,
                   params: ValveParameters) -> None:
    """The picked support's moved parameters, errors, structure explained, confidence and
    currents, set on ``out``."""
    fit, val = ref.fit, ref.val
    moved = ValveParameters.from_vector(pick.raw)
    out.baseline_parameters = {n: float(getattr(moved, n)) for n in IDENTIFIED_FIELDS}
    out.errors = {'baseline_fit': _figures(fit, ref.res_f), 'baseline_validation':
                  _figures(val, ref.res_v), 'augmented_fit': _figures(fit, pick.after_f),
                  'augmented_validation': _figures(val, pick.after_v)}
    noise = noise_per_file(val, params)
    before = structured_energy_of(ref.res_v, noise)
    out.structure_explained = (1.0 - structured_energy_of(pick.after_v, noise) / before
                               if before > 0 else 0.0)
    out.confidence = 'medium' if out.structure_explained >= MIN_EXPLAINED else 'low'
    out.currents = {'fit': [m.current_a - r for m, r in zip(fit.measurements, pick.after_f)],
                    'validation': [m.current_a - r
                                   for m, r in zip(val.measurements, pick.after_v)]}
    out.reason = pick.model.reason


def search_unlisted(fit: FitData, val: FitData | None, params: ValveParameters
                    ) -> UnlistedResult:
    """Fit the sparse voltage-balance term (module notes) and judge it on the hold-out data.

    The baseline parameters move with the term (as a listed candidate's refit moves
    them): the STLSQ path is computed with their current Jacobian projected out, each
    support's joint least-squares step is applied to them in the kernel, and the term's
    coefficients are refitted along the new trajectory.

    Parameters
    ----------
    fit, val : FitData
        Fit and validation data (bare-coil records); without ``val`` nothing is tried
        (the hold-out criterion cannot be checked).
    params : ValveParameters
        The baseline parameters.

    Returns
    -------
    UnlistedResult
    """
    names = list(LIBRARY)
    equation = ('V = R i + d(lambda)/dt + sum_k xi_k theta_k, theta in {' + ', '.join(names)
                + '} (effect on the current linearised along the model, spool motion held)')
    if fit.through_electronics or (val is not None and val.through_electronics):
        return UnlistedResult(False, False, 'not offered for records through the drive '
                              'electronics: the chopper regulates the current', equation)
    if val is None:
        return UnlistedResult(False, False, 'not offered without validation data: the '
                              'sparse term is selected on the hold-out data', equation)
    space = baseline_space(params)
    raw0 = params.to_vector()
    sim_f0, sim_v0 = _simulate(fit, raw0, names), _simulate(val, raw0, names)
    J = _stack(fit, file_jacobians(space, fit, params))
    jn = np.linalg.norm(J, axis=0)
    jn = np.where(jn > 0, jn, 1.0)
    A = _stack(fit, sim_f0.responses)
    b = _stack(fit, [np.where(np.isfinite(r), r, 0.0) for r in sim_f0.residual])
    Ap, bp = _project_out(J / jn, A, b)
    supports = stlsq_path(Ap, bp)
    ref = _Reference(fit, val, sim_f0.residual, sim_v0.residual,
                     effective_counts(fit, params), effective_counts(val, params),
                     resolution_floors(fit), resolution_floors(val),
                     _mae(fit, sim_f0.residual), _mae(val, sim_v0.residual))
    path: list[_Offer] = []
    for s in supports:
        joint = np.column_stack([J / jn, A[:, list(s)]])
        z, *_ = np.linalg.lstsq(joint, b, rcond=1e-8)
        ev = _evaluate(space, fit, val, params, names, s, z[:J.shape[1]] / jn)
        if ev is not None:
            path.append(_judge_support(s, ev, names, ref))
    path.sort(key=lambda e: e.model.dbic_val if math.isfinite(e.model.dbic_val) else math.inf)
    passing = [e for e in path if e.model.passes]
    pick = passing[0] if passing else (path[0] if path else None)
    out = UnlistedResult(True, bool(passing), '', equation, pick.model if pick else None,
                         [e.model for e in path])
    if pick is None:
        out.reason = 'no usable library column'
        return out
    _describe_pick(out, pick, ref, params)
    return out


def _unit(term: str) -> str:
    """Unit of a term's coefficient in the voltage balance."""
    u = LIBRARY[term][0]
    return 'V' if u == '1' else f'V/({u})' if ' ' in u else f'V/{u}'


def _term_text(model: SparseModel) -> str:
    return ' + '.join(f'({v:.4g} {_unit(n)}) {n}' for n, v in model.coefficients.items())


def offer_unlisted(diag: Diagnosis, fit: FitData, val: FitData | None,
                   params: ValveParameters, say: Callable[[str], None] | None = None
                   ) -> UnlistedResult | None:
    """After a ``none`` with unexplained structure: try the sparse term, update ``diag``.

    A sparse model that pays turns the answer into ``unlisted`` (confidence ``medium`` or
    ``low``, the augmented parameters stay the baseline's: the kernel cannot simulate the
    term). Otherwise the answer stays ``none`` and the evidence says what was tried.
    """
    say = say or (lambda s: None)
    if diag.effect != 'none' or not diag.unexplained_structure:
        return None
    misfit = list(diag.numbers.get('baseline_at_search_bound') or [])
    res = search_unlisted(fit, val, params)
    if res.tried and misfit and res.claimed:
        # The misfit of a baseline at a bound is not read as a missing effect.
        res.claimed = False
        res.reason = ('a sparse term pays, but the baseline has parameters at a search bound '
                      '(' + ', '.join(misfit) + '): its residual is a misfit, not read as an '
                      'effect; not claimed')
    diag.unlisted = res
    m = res.model
    if not res.tried:
        diag.evidence.append(f'open-ended sparse augmentation not tried: {res.reason}')
        return res
    if res.claimed and m is not None:
        e = res.errors
        diag.effect = 'unlisted'
        diag.confidence = res.confidence
        diag.evidence.append(
            'an effect outside the candidate list: a sparse term in the voltage balance '
            f'pays for its {len(m.terms)} term(s) on fit and validation data (dBIC fit '
            f'{m.dbic_fit:.0f}, validation {m.dbic_val:.0f}): V = R i + d(lambda)/dt + '
            + _term_text(m))
        diag.evidence.append(
            f'current RMSE with the term: fit {1e3 * e["baseline_fit"]["rmse"]:.2f} -> '
            f'{1e3 * e["augmented_fit"]["rmse"]:.2f} mA, validation '
            f'{1e3 * e["baseline_validation"]["rmse"]:.2f} -> '
            f'{1e3 * e["augmented_validation"]["rmse"]:.2f} mA (validation mean absolute '
            f'error {100 * m.val_gain:.1f} % lower); it removes '
            f'{100 * res.structure_explained:.0f} % of the validation residual energy beyond '
            f'the noise; confidence {res.confidence}')
        diag.evidence.append('the model cannot simulate this term: params.yaml holds the '
                             'baseline parameters, the term is in report.json under '
                             '"unlisted"')
        diag.unexplained_structure = res.structure_explained < 0.9
        diag.numbers['unlisted_terms'] = m.terms
        say(f'unlisted term: {_term_text(m)}; validation error {100 * m.val_gain:.1f} % '
            f'lower -> diagnosis unlisted (confidence {res.confidence})')
    else:
        best = (f'; best sparse model {" + ".join(m.terms)}: validation error '
                f'{100 * m.val_gain:+.2f} % ({m.reason})') if m is not None else ''
        diag.evidence.append('an open-ended sparse term in the voltage balance (library: '
                             + ', '.join(LIBRARY) + ') was tried and does not pay either'
                             + (f': {res.reason}' if misfit and res.reason else '') + best
                             + '; the structure stays unexplained')
        say('unlisted term: none pays' + best)
    return res
