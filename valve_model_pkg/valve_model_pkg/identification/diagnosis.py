"""Closing the loop: trace the residual to an effect the model lacks, or to none.

Three steps after the baseline fit:

1. **Signatures.** For each effect of the model's registry
   (:data:`~valve_model_pkg.model.parameters.EFFECTS`) the current is simulated with the
   effect switched on at a moderate probe value; the difference to the baseline is the
   effect's *signature*. The part of it that the baseline parameters can imitate (their
   Jacobian) is projected out, and the residual is correlated with what is left. A large
   positive correlation says "this effect's fingerprint is in the residual". This is a
   score test; it ranks the candidates and is reported as evidence.
2. **Refits.** The leading candidates (by default all six, they are cheap) are refitted:
   the eight baseline parameters plus the effect's one or two, by the same direct search
   started from the baseline optimum with a few values of the effect.
3. **Selection.** An effect is kept only if it pays for its extra parameters twice:

   * on the fit data, the Bayesian information criterion of a Laplace (absolute-error)
     likelihood, ``dBIC = sum_f 2 n_f ln(MAE_aug,f / MAE_base,f) + p ln(n)``, is below
     ``-10`` (strong evidence);
   * on the validation data (a hold-out experiment the fit never saw), the same
     criterion with the validation files is below ``-10``, i.e. the validation error
     falls by more than the extra parameters buy, and by at least 2 % in absolute error.

   Among the kept candidates the one with the largest validation gain wins. It is
   *claimed* only if it also explains the residual's structure: at least half of the
   validation residual's energy beyond the noise must go. Otherwise the answer is
   ``none`` with the residual's structure reported as unexplained: an effect outside the
   list may be at work, and a listed one is not claimed with confidence it lacks.
"""
from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..model.parameters import EFFECTS, ValveParameters
from .criteria import (DBIC_THRESHOLD, MIN_EXPLAINED, MIN_VALIDATION_GAIN, delta_bic,
                       effective_counts, noise_per_file, resolution_floors, structured_energy)
from .phase import PHASE_RESOLUTION_S, AmountPhases, phase_free, place, placed, shiftable
from .problem import (ErrorFigures, FitData, ParameterSpace, amount_limit, effect_space,
                      unit_objective, with_upper_bound)
from .residuals import drive_phase_masks, ljung_box
from .search import SearchResult, SearchSettings, direct_search
from .sensitivity import noise_std, perturbed_values

__all__ = ['CandidateResult', 'Diagnosis', 'RefitResult', 'score_signatures', 'refit_effect',
           'widen_at_bound', 'select', 'second_effect', 'describe_misfit',
           'describe_remaining', 'effect_scan', 'slow_effect', 'indistinguishable_runners_up']

#: Structured residual RMS (beyond noise), relative to the noise, that counts as structure.
STRUCTURE_FRACTION = 0.3
#: Ljung-Box p-value below which a residual counts as structured whatever its size.
WHITENESS_P = 1e-4

# Probe values for the signatures: a moderate amount of each effect, as a fraction of the
# registry's range for the first field of each effect (heating keeps its time constant).
_PROBE_FRACTION = 0.15
# Trial amounts of the profile stage of a refit, as fractions of the registry's range.
_PROFILE_FRACTIONS = (0.02, 0.08, 0.2, 0.4, 0.7)
# Amounts of the scan before the profile: the effect alone, every other parameter held at
# the baseline optimum and at the prior (one batch of simulations each). Spacing 0.04 of
# the range: an effect whose cost is sharp in its amount (a leakage inductance through the
# chopper: 25 mH fits to 0.6 mA, 20 or 30 mH only to 6 mA) falls between the profile's
# trial amounts, and the scan finds where to add one.
_SCAN_FRACTIONS = tuple(float(f) for f in np.linspace(0.02, 0.98, 25))
# An effect with a time constant (coil heating: amount R_th, time constant tau) is scanned
# in (initial rate R_th / tau, tau), log-spaced, 25 x 7 points: on a record shorter than
# tau the current carries the rate (dT ~ R_th P t / tau), so amount and time constant trade
# off along a valley of constant rate. A scan at one fixed tau misses the valley when the
# true tau is far from it, and an axis-aligned grid in (R_th, tau) steps over it (its best
# points lie between the valley's, at several times the hold-out error of the right pair).
# Two zooms follow the valley: 9 x 9 points one step either side of the best, then of the
# zoom's best.
_SCAN_RATES, _SCAN_TAUS, _ZOOMS = 25, 7, 2


def _time_constant_field(effect: str) -> str | None:
    """The effect's time-constant field (a further field named ``*_time_constant_s``)."""
    taus = [f for f in EFFECTS[effect].fields[1:] if f.endswith('_time_constant_s')]
    return taus[0] if taus else None


def slow_effect(effect: str, span_s: float) -> bool:
    """True if ``effect``'s shortest time constant (the lower bound of its time-constant
    field) is longer than ``span_s``: a window that short cannot show it, and its refit
    searches the whole fit window instead of the search window."""
    tau = _time_constant_field(effect)
    return tau is not None and EFFECTS[effect].bounds[tau][0] > span_s


def _rate_tau_points(effect: str, centre: tuple[float, float] | None, level: int
                     ) -> np.ndarray:
    """(amount, tau) of the scan in log10 rate and log10 tau: the coarse grid, or the zoom
    of ``level`` (1, 2, ...) around ``centre`` = (log10 rate, log10 tau)."""
    spec = EFFECTS[effect]
    amount, tau = spec.fields[0], _time_constant_field(effect)
    a_hi = spec.bounds[amount][1]
    t_lo, t_hi = (math.log10(v) for v in spec.bounds[tau])
    lt = np.linspace(t_lo + 0.05 * (t_hi - t_lo), t_hi - 0.05 * (t_hi - t_lo), _SCAN_TAUS)
    lr = np.linspace(math.log10(0.02 * a_hi) - t_hi, math.log10(0.98 * a_hi) - t_lo,
                     _SCAN_RATES)
    if centre is not None:
        wr, wt = (lr[1] - lr[0]) / 4 ** (level - 1), (lt[1] - lt[0]) / 4 ** (level - 1)
        lr = centre[0] + np.linspace(-wr, wr, 9)
        lt = np.clip(centre[1] + np.linspace(-wt, wt, 9), t_lo, t_hi)
    g_r, g_t = (x.ravel() for x in np.meshgrid(lr, lt, indexing='ij'))
    a = 10.0 ** (g_r + g_t)
    keep = a <= a_hi
    return np.column_stack([a[keep], 10.0 ** g_t[keep]])


def effect_scan(ext: ParameterSpace, effect: str, origin: np.ndarray,
                around: np.ndarray | None = None, level: int = 1) -> np.ndarray:
    """The scan's points around ``origin`` (unit coordinates of ``ext``), every coordinate but
    the effect's at ``origin``. Shape (m, ext.size).

    The effect's first field over :data:`_SCAN_FRACTIONS` of its range; an effect with a
    time constant over a log grid of (rate amount / tau, tau) instead (see
    :data:`_SCAN_RATES`), and with ``around`` (a scanned point) the zoom of ``level``
    around it. Other further fields are held at ``origin``."""
    fields = EFFECTS[effect].fields
    first = ext.names.index(fields[0])
    tau = _time_constant_field(effect)
    if tau is None:
        trial = np.repeat(origin[None, :], len(_SCAN_FRACTIONS), axis=0)
        trial[:, first] = _SCAN_FRACTIONS
        return trial
    j_tau = ext.names.index(tau)
    b_a, b_t = ext.bounds[first], ext.bounds[j_tau]
    centre = None
    if around is not None:
        a_c = float(b_a.from_unit(np.array(around[first])))
        t_c = float(b_t.from_unit(np.array(around[j_tau])))
        centre = (math.log10(max(a_c, 1e-12) / t_c), math.log10(t_c))
    pts = _rate_tau_points(effect, centre, level)
    trial = np.repeat(origin[None, :], len(pts), axis=0)
    trial[:, first] = [b_a.to_unit(v) for v in pts[:, 0]]
    trial[:, j_tau] = [b_t.to_unit(v) for v in pts[:, 1]]
    return trial


@dataclass
class CandidateResult:
    """One candidate effect: its signature score, its refit, its verdict."""

    effect: str
    fields: tuple[str, ...]
    signature_correlation: float = math.nan
    signature_amplitude: float = math.nan
    refitted: bool = False
    parameters: dict[str, float] = field(default_factory=dict)
    params: ValveParameters | None = None
    fit_cost: float = math.nan
    val_cost: float = math.nan
    fit_gain: float = math.nan
    val_gain: float = math.nan
    dbic_fit: float = math.nan
    dbic_val: float = math.nan
    structure_explained: float = math.nan
    kept: bool = False
    reason: str = ''
    bound_widened: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, object]:
        def f(x: float) -> float | None:
            return None if x is None or (isinstance(x, float) and not math.isfinite(x)) \
                else x
        return {
            'effect': self.effect,
            'extra_parameters': {k: f(v) for k, v in self.parameters.items()},
            'signature_correlation': f(self.signature_correlation),
            'refitted': self.refitted,
            'fit_error_reduction_pct': f(100.0 * self.fit_gain),
            'validation_error_reduction_pct': f(100.0 * self.val_gain),
            'delta_bic_fit': f(self.dbic_fit),
            'delta_bic_validation': f(self.dbic_val),
            'structure_explained_pct': f(100.0 * self.structure_explained),
            'kept': self.kept,
            'reason': self.reason,
            'search_bound_widened': self.bound_widened,
        }


@dataclass
class Diagnosis:
    """Outcome of the effect selection."""

    effect: str
    confidence: str
    candidates: list[CandidateResult]
    evidence: list[str]
    numbers: dict[str, object]
    params: ValveParameters
    unexplained_structure: bool
    #: Effects in the augmented model (the claimed one, and a second that paid too).
    kept_effects: list[str] = field(default_factory=list)
    #: Candidates the data cannot tell from the claimed one.
    indistinguishable: list[str] = field(default_factory=list)
    second: dict[str, object] | None = None
    remaining: dict[str, object] | None = None
    #: Judged on (set by select): data and the baseline's noise, for the second effect.
    judge: object = None
    base_mae: dict | None = None
    #: The open-ended sparse augmentation (:mod:`.unlisted`), when it was tried.
    unlisted: object = None
    #: The baseline misfit no candidate explains, stated (:func:`describe_misfit`).
    misfit: dict[str, object] | None = None


def _stack(data: FitData, arrays: list[np.ndarray]) -> np.ndarray:
    """Valid samples of all files, each scaled so every file weighs the same (as the cost)."""
    out = []
    for a, w, T, valid in zip(arrays, data.weights, data.durations, data.valid):
        out.append(a[valid] * np.sqrt(w[valid] / T))
    return np.concatenate(out)


def _probe(params: ValveParameters, effect: str, fraction: float) -> ValveParameters:
    spec = EFFECTS[effect]
    name = spec.fields[0]
    lo, hi = spec.bounds[name]
    return params.replace(**{name: spec.neutral[name] + fraction * (hi - lo)})


#: Shift of the main PWM grids whose difference gives the phase's direction [s]
#: (:func:`_phase_columns`): two periods of a 40 kHz hysteresis clock, so the secant
#: does not follow the chopper's limit cycle.
PHASE_PROBE_S = 50e-6


def _phase_columns(data: FitData, params: ValveParameters) -> list[np.ndarray]:
    """The current's derivative along each movable main PWM grid's phase at ``params``
    (a secant over :data:`PHASE_PROBE_S` either side, within the range the record allows),
    stacked as :func:`_stack` does, one column per file whose grid may move. The phase is
    fitted with each model (:mod:`.phase`): the part of an effect's signature along it is
    taken by the phase, not the effect."""
    free = [phase_free(m) for m in data.full]
    if not any(free):
        return []
    up = [min(PHASE_PROBE_S, m.drive.phase_range_s[1]) if f else 0.0
          for m, f in zip(data.full, free)]
    down = [min(PHASE_PROBE_S, -m.drive.phase_range_s[0]) if f else 0.0
            for m, f in zip(data.full, free)]
    raw = params.to_vector()[None, :]
    plus = placed(data, up).simulate(raw)
    minus = placed(data, [-d for d in down]).simulate(raw)
    cols = []
    for k in range(len(free)):   # p, q: a file's (1, n) currents
        span = up[k] + down[k]
        if not free[k] or span <= PHASE_RESOLUTION_S:
            continue
        cols.append(_stack(data, [(p[0] - q[0]) / span if j == k else np.zeros(p.shape[1])
                                  for j, ((p, _), (q, _)) in enumerate(zip(plus, minus))]))
    return cols


def score_signatures(space: ParameterSpace, data: FitData, params: ValveParameters,
                     residuals: list[np.ndarray]) -> dict[str, tuple[float, float]]:
    """Correlation of the residual with each effect's signature, the part along the baseline
    parameters and the main PWM grids' phases removed.

    Returns
    -------
    dict
        effect -> (correlation in [-1, 1], amplitude); the amplitude is the multiple of
        the probe signature that best fits the residual (negative = the wrong sign, the
        effect cannot produce it).
    """
    base = params.to_vector()
    n = space.size
    vrows, denom = perturbed_values(space, params, 0.01)
    effects = list(EFFECTS)
    raw = np.vstack([base[None, :], space.raw_from_values(vrows)]
                    + [_probe(params, eff, _PROBE_FRACTION).to_vector()[None, :]
                       for eff in effects])
    ok = space.feasible(raw)
    raw[~ok] = base
    sims = [c for c, _ in data.simulate(raw)]
    res = _stack(data, [np.where(np.isfinite(r), r, 0.0) for r in residuals])
    cols = []
    for j in range(n):
        cols.append(_stack(data, [(c[1 + 2 * j] - c[2 + 2 * j]) / denom[j] for c in sims]))
    jac = np.column_stack(cols + _phase_columns(data, params))
    out = {}
    for k, eff in enumerate(effects):
        sig = _stack(data, [c[1 + 2 * n + k] - c[0] for c in sims])
        coef, *_ = np.linalg.lstsq(jac, sig, rcond=None)
        perp = sig - jac @ coef
        nrm = float(np.linalg.norm(perp)) * float(np.linalg.norm(res))
        if nrm == 0.0:
            out[eff] = (0.0, 0.0)
            continue
        dot = float(perp @ res)
        out[eff] = (dot / nrm, dot / float(perp @ perp))
    return out


@dataclass
class RefitResult:
    """A candidate's refit (:func:`refit_effect`).

    Attributes
    ----------
    params : ValveParameters
        The refitted parameters (baseline parameters and the effect's).
    cost : float
        Their cost on the data searched [A].
    space : ParameterSpace
        The baseline space extended by the effect's fields.
    stopped : bool
        True when the search stopped after the coarse profile: no trial amount brought the
        cost below ``bar_cost``.
    screen_dbic : float
        The fit criterion's dBIC after the coarse profile when ``screen`` was given (nan
        otherwise); the refit stops there when it is not below :data:`SCREEN_DBIC`.
    widened : tuple of str
        One line per widening of the effect's search bound (:func:`widen_at_bound`).
    """

    params: ValveParameters
    cost: float
    space: ParameterSpace
    stopped: bool = False
    screen_dbic: float = math.nan
    widened: tuple[str, ...] = ()

    @property
    def screened_out(self) -> bool:
        """True when the screen after the coarse profile stopped the refit."""
        return not math.isnan(self.screen_dbic) and not self.screen_dbic < SCREEN_DBIC


def _profile_starts(u_base: np.ndarray, first: int) -> list[np.ndarray]:
    """One start per trial amount of :data:`_PROFILE_FRACTIONS`, the rest at ``u_base``."""
    starts = []
    for frac in _PROFILE_FRACTIONS:
        u = u_base.copy()
        u[first] = frac
        starts.append(u)
    return starts


def _scan_best(ext: ParameterSpace, effect: str, origin: np.ndarray,
               fun: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, float] | None:
    """The best point of the effect's scan around ``origin`` (with its zooms for an
    effect with a time constant) and its cost; None when no scanned point is feasible."""
    trial = effect_scan(ext, effect, origin)
    costs = fun(trial)
    for level in range(1, _ZOOMS + 1):
        if _time_constant_field(effect) is None or not np.isfinite(costs).any():
            break
        zoom = effect_scan(ext, effect, origin, around=trial[int(np.argmin(costs))],
                           level=level)
        trial, costs = np.vstack([trial, zoom]), np.concatenate([costs, fun(zoom)])
    if not np.isfinite(costs).any():
        return None
    best = int(np.argmin(costs))
    return trial[best].copy(), float(costs[best])


def _fine_starts(res_u: np.ndarray, fractions: list[float], first: int) -> np.ndarray:
    """Starts of the fine profile: four amounts between the best trial amount and its
    neighbours on the grid of ``fractions``, from the baseline parameters that amount
    found, and the best point itself."""
    grid = np.array(sorted(set(fractions)))
    k = int(np.argmin(np.abs(grid - res_u[first])))
    lo = grid[k - 1] if k > 0 else 0.0
    hi = grid[k + 1] if k + 1 < grid.size else 1.0
    fine = []
    for frac in (lo + 0.5 * (grid[k] - lo), grid[k] - 0.25 * (grid[k] - lo),
                 grid[k] + 0.25 * (hi - grid[k]), grid[k] + 0.5 * (hi - grid[k])):
        u = res_u.copy()
        u[first] = frac
        fine.append(u)
    fine.append(res_u.copy())
    return np.array(fine)


def refit_effect(space: ParameterSpace, data: FitData, params: ValveParameters, effect: str,
                 settings: SearchSettings, progress: Callable[[str], None] | None = None,
                 bar_cost: float | None = None, rank_data: FitData | None = None,
                 screen: Callable[[ValveParameters], float] | None = None) -> RefitResult:
    """Refit the baseline parameters plus one effect's, from the baseline optimum.

    Profile first: one simplex per trial amount of the effect, the effect held there while
    the baseline parameters adapt (they trade off strongly against most effects, so a joint
    simplex started at the baseline optimum tends to stall near it). Then a fine profile
    around the best amount, between its neighbours on the grid, and restarts that free
    everything: without that second look the free restarts rarely leave the grid value,
    as the effect and the baseline parameters have to move together.

    Parameters
    ----------
    space : ParameterSpace
        The baseline space.
    data : FitData
        The data searched.
    params : ValveParameters
        The baseline optimum.
    effect : str
        Name of the effect (:data:`~valve_model_pkg.model.parameters.EFFECTS`).
    settings : SearchSettings
        Effort of the profiles.
    progress : callable, optional
        Receives progress lines.
    bar_cost : float, optional
        The baseline's own cost on ``data`` [A]. When none of the coarse profile's trial
        amounts (nor the scan) brings the cost below it, the effect cannot pay and the fine
        profile is skipped (``stopped``): records through the electronics, where each
        simulation is dear.
    rank_data : FitData, optional
        The whole fit window when ``data`` is a search window (records through the
        electronics). The effect's amount is then first scanned (:func:`effect_scan`) with
        every other parameter at the baseline optimum and at the prior, one batch each;
        the coarse profile's best and the scan's best are compared on ``rank_data`` and the
        fine profile starts from the better: a short search window can hold a
        compensating basin (the baseline parameters at a bound standing in for the effect)
        as well as the effect's own, and the longer record tells them apart. Step records
        keep the profile alone.
    screen : callable, optional
        The fit criterion's dBIC of a parameter set on the data searched. After the coarse
        profile a refit whose dBIC is not below :data:`SCREEN_DBIC` stops: it does not pay
        even before the criterion's margin, and the fine profile only moves the amount
        between neighbouring trial amounts.

    Returns
    -------
    RefitResult
    """
    ext = effect_space(space, effect)
    u_base = ext.to_unit(params)
    first = ext.names.index(EFFECTS[effect].fields[0])
    phases = AmountPhases(data, EFFECTS[effect].fields[0]) if shiftable(data) else None
    fun = _objective(ext, data, phases)
    fractions = list(_PROFILE_FRACTIONS)
    starts = _profile_starts(u_base, first)
    _anchor(phases, ext, starts)
    scanned: list[tuple[np.ndarray, float]] = []
    origins = []
    if rank_data is not None:
        origins = [u_base]
        u_prior = ext.to_unit(space.base)
        if float(np.max(np.abs(np.delete(u_prior - u_base, first)))) > 0.05:
            origins.append(u_prior)   # the prior (packaged set or --params), if elsewhere
    for origin in origins:
        found = _scan_best(ext, effect, origin, fun)
        if found is not None:
            starts.append(found[0].copy())
            fractions.append(float(found[0][first]))
            scanned.append(found)
    coarse = replace(settings, restarts=0)
    res = direct_search(fun, np.array(starts), coarse, progress=progress,
                        label=f'refit {effect}', fixed=np.array([first]))
    if bar_cost is not None and not min([res.cost] + [c for _, c in scanned]) < bar_cost:
        return RefitResult(ext.params(res.u), res.cost, ext, stopped=True)
    if rank_data is not None and scanned:
        points = np.array([res.u] + [u for u, _ in scanned])
        ranked = _placed_costs(ext, rank_data, points)
        pick = int(np.argmin(ranked))
        if pick > 0:   # a scanned point beats the profile's best on the whole fit window
            u_pick, c_pick = scanned[pick - 1]
            res = replace(res, u=u_pick, cost=c_pick)
    d = math.nan
    if screen is not None:
        d = screen(ext.params(res.u))
        if not d < SCREEN_DBIC:
            return RefitResult(ext.params(res.u), res.cost, ext, screen_dbic=d)
    fine = _fine_starts(res.u, fractions, first)
    _anchor(phases, ext, fine)
    res2 = direct_search(fun, fine, replace(settings, initial_step=0.5 * settings.initial_step),
                         progress=progress, label=f'refit {effect} (fine)',
                         fixed=np.array([first]))
    best = res2 if res2.cost <= res.cost else res
    return widen_at_bound(RefitResult(ext.params(best.u), best.cost, ext, screen_dbic=d),
                          data, effect, settings, progress, phases)


def _objective(space: ParameterSpace, data: FitData, phases: AmountPhases | None):
    """The batch objective of a refit: on the grids placed per amount when the records'
    main PWM grids may move (:class:`~.phase.AmountPhases`), else on ``data``."""
    return phases.objective(space) if phases is not None else unit_objective(space, data)


def _anchor(phases: AmountPhases | None, space: ParameterSpace, starts: Sequence) -> None:
    """Place the grids exactly at each start of a profile (its trial amount)."""
    if phases is not None:
        for u in starts:
            phases.anchor(space.params(np.asarray(u)))


def _placed_costs(space: ParameterSpace, data: FitData, points: np.ndarray) -> np.ndarray:
    """Cost of each point on ``data``, each on the grids placed at its own parameters."""
    if not shiftable(data):
        return unit_objective(space, data)(points)
    return np.array([float(unit_objective(space, place(data, space.params(u)))(u[None, :])[0])
                     for u in points])


#: An effect's refit whose amount ends within this share of its range from the upper search
#: bound reached the bound (:func:`widen_at_bound`); as :meth:`FitData.at_bound`.
BOUND_FRACTION = 0.01
#: Factor of one widening of the upper bound, and the most widenings of one refit.
WIDEN_FACTOR = 3.0
MAX_WIDENINGS = 2
#: The data determine an amount at its bound when stepping it back by a tenth of its range
#: (everything else held) raises the cost by more than this share: along a direction the
#: data do not see the cost stays flat, and a bound there is no reason to search further.
DETERMINED_RISE = 1e-3

_UNITS = {'coulomb_friction_n': 'N', 'leakage_inductance_h': 'H', 'eddy_conductance_s': 'S'}


def _determined_at_bound(r: RefitResult, data: FitData, first: int,
                         phases: AmountPhases | None = None) -> bool:
    """True when the cost rises (:data:`DETERMINED_RISE`) as the amount steps back."""
    u = r.space.to_unit(r.params)
    back = u.copy()
    back[first] = 0.9
    _anchor(phases, r.space, [back])
    cost = _objective(r.space, data, phases)(np.vstack([u, back]))
    return bool(cost[1] > cost[0] * (1.0 + DETERMINED_RISE))


def _widened_profile(wide: ParameterSpace, data: FitData, params: ValveParameters,
                     first: int, settings: SearchSettings,
                     progress: Callable[[str], None] | None, label: str,
                     phases: AmountPhases | None = None) -> SearchResult:
    """The profiles of :func:`refit_effect` over the widened part of the range, from the
    bound-hitting point ``params``: trial amounts from the old bound to the new one."""
    u0 = wide.to_unit(params)
    fractions = [float(u0[first] + (1.0 - u0[first]) * f)
                 for f in (0.0, 0.25, 0.5, 0.75, 1.0)]
    starts = []
    for frac in fractions:
        u = u0.copy()
        u[first] = frac
        starts.append(u)
    _anchor(phases, wide, starts)
    fun = _objective(wide, data, phases)
    res = direct_search(fun, np.array(starts), replace(settings, restarts=0),
                        progress=progress, label=label, fixed=np.array([first]))
    fine = _fine_starts(res.u, fractions, first)
    _anchor(phases, wide, fine)
    res2 = direct_search(fun, fine,
                         replace(settings, initial_step=0.5 * settings.initial_step),
                         progress=progress, label=f'{label} (fine)', fixed=np.array([first]))
    return res2 if res2.cost <= res.cost else res


def widen_at_bound(r: RefitResult, data: FitData, effect: str, settings: SearchSettings,
                   progress: Callable[[str], None] | None = None,
                   phases: AmountPhases | None = None) -> RefitResult:
    """Widen the upper search bound of an effect amount that its refit reached, and refit.

    When the effect's first field ends within :data:`BOUND_FRACTION` of its upper bound,
    the data determine it there (:func:`_determined_at_bound`) and it has a physical limit
    above the bound (:func:`~.problem.amount_limit` of the space's base: the measured
    values, which the refit may have moved to their own bounds), the bound grows by
    :data:`WIDEN_FACTOR` (at most to the limit) and the profiles run again over the new
    part of the range from the bound-hitting point; at most :data:`MAX_WIDENINGS` times.
    A widened refit that does not lower the cost is dropped (the refit at the bound stays).
    Each widening is said in ``r.widened``. A refit that never reaches its bound is
    returned unchanged.
    """
    name = EFFECTS[effect].fields[0]
    unit = _UNITS.get(name, '')
    for _ in range(MAX_WIDENINGS):
        first = r.space.names.index(name)
        bound = r.space.bounds[first]
        limit = amount_limit(name, r.space.base)
        if (r.space.to_unit(r.params)[first] < 1.0 - BOUND_FRACTION or limit is None
                or not _determined_at_bound(r, data, first, phases)):
            break
        if not limit.value > bound.high:
            r = replace(r, widened=r.widened + (
                f'{name} reached its physical limit, {limit.why} {limit.value:.4g} {unit}: '
                'not widened further',))
            break
        high = min(WIDEN_FACTOR * bound.high, limit.value)
        wide = with_upper_bound(r.space, name, high)
        res = _widened_profile(wide, data, r.params, first, settings, progress,
                               f'refit {effect} (bound widened)', phases)
        note = (f'{name} reached its search bound {bound.high:.4g} {unit}: widened to '
                f'{high:.4g} {unit} ({limit.why} {limit.value:.4g} {unit})')
        if not res.cost < r.cost:
            r = replace(r, widened=r.widened + (note + '; no lower cost there: kept at the '
                                                'bound',))
            break
        p = wide.params(res.u)
        note += f', refitted to {getattr(p, name):.4g} {unit}'
        if progress:
            progress(note)
        r = replace(r, params=p, cost=float(res.cost), space=wide, widened=r.widened + (note,))
    return r


def _has_release(m: object) -> bool:
    """True if the voltage falls to (near) zero after having been on for a while."""
    v = np.abs(m.voltage_v)
    on = v > 0.5 * v.max() if v.max() > 0 else np.zeros(v.size, bool)
    if not on.any():
        return False
    first = int(np.argmax(on))
    return bool(np.any(v[first:] < 0.1 * v.max()))


#: A refit whose coarse profile leaves the fit criterion's dBIC at or above this stops
#: there (:func:`refit_effect`'s ``screen``): to be kept it would need the fine profile to
#: gain more than ``-DBIC_THRESHOLD`` more, and the fine profile only moves the amount
#: between neighbouring trial amounts, which changes the cost of an effect the trial
#: amounts miss by a fraction of a per cent.
SCREEN_DBIC = 0.0
#: A runner-up that gains this share of the winner's validation gain cannot be told apart
#: (unless the hold-out criterion rejects it: :func:`indistinguishable_runners_up`).
INDISTINGUISHABLE = 0.8
#: Structured RMS left after the claimed effect, relative to the noise, above which the
#: claim is only of low confidence (something else is at work, maybe outside the list).
REMAINING_STRUCTURE = 1.0
#: Share of the structure the claimed effect must remove for confidence high.
HIGH_CONFIDENCE_EXPLAINED = 0.7
#: Share of the structure removed below which some of it is reported as unexplained.
FULLY_EXPLAINED = 0.9


@dataclass
class Reference:
    """The baseline the candidates are judged against (:func:`select`).

    Attributes
    ----------
    fit_errors, validation_errors : ErrorFigures
        The baseline's errors on the fit and validation data (None without validation).
    fit_floors, validation_floors, judge_floors : dict
        Resolution floor of each file [A] (``judge_floors``: of ``judge``).
    judge : FitData
        The data the structure is judged on: the validation data, else the fit data.
    noise : list of float
        Noise of each file of ``judge`` from the baseline residual [A].
    structured_energy : float
        The baseline residual's energy beyond the noise on ``judge`` [A^2].
    """

    fit_errors: ErrorFigures
    validation_errors: ErrorFigures | None
    fit_floors: dict[str, float]
    validation_floors: dict[str, float]
    judge_floors: dict[str, float]
    judge: FitData
    noise: list[float]
    structured_energy: float


def _reference(fit: FitData, val: FitData | None, baseline: ValveParameters) -> Reference:
    judge = val if val is not None else fit
    noise = noise_per_file(judge, baseline)
    fit_floors = resolution_floors(fit)
    val_floors = resolution_floors(val) if val is not None else {}
    return Reference(fit_errors=fit.errors(baseline),
                     validation_errors=val.errors(baseline) if val is not None else None,
                     fit_floors=fit_floors, validation_floors=val_floors,
                     judge_floors=val_floors if val is not None else fit_floors,
                     judge=judge, noise=noise,
                     structured_energy=structured_energy(judge, baseline, noise))


def _judge_candidate(c: CandidateResult, ref: Reference, fit: FitData, val: FitData | None,
                     at_bound: list[str], space: ParameterSpace | None,
                     determined: Collection[str] | None = None) -> None:
    """Apply the keep rule to one refitted candidate: its errors, dBICs, the structure it
    explains, ``kept`` and the reason in words (set on ``c``). A refit parameter at a
    search bound counts against it only if the data determine it (``determined``; all
    when None), as for the baseline: the damping of a step record, which the friction
    force dwarfs, may sit at a bound without any misfit."""
    p = len(c.fields)
    # Each model on its own main PWM grids (:mod:`.phase`): the baseline's were placed at
    # its optimum, the candidate's are placed at its refit.
    fit, val = place(fit, c.params), place(val, c.params) if val is not None else None
    judge = place(ref.judge, c.params)
    # Independent samples are counted in the residual of the model under test (the
    # augmented one): the baseline's misfit is the very structure the candidate may
    # remove, and counted there it would leave a handful of samples and hide a candidate
    # that removes most of the error. A candidate that does not fit keeps a structured
    # residual, so its count stays small.
    aug_fit = fit.errors(c.params)
    c.fit_cost = sum(aug_fit.mae_per_file.values())
    c.fit_gain = 1.0 - c.fit_cost / sum(ref.fit_errors.mae_per_file.values())
    c.dbic_fit = delta_bic(ref.fit_errors.mae_per_file, aug_fit.mae_per_file,
                           effective_counts(fit, c.params), p, ref.fit_floors)
    if val is not None and ref.validation_errors is not None:
        aug_val = val.errors(c.params)
        c.val_cost = sum(aug_val.mae_per_file.values())
        c.val_gain = 1.0 - c.val_cost / sum(ref.validation_errors.mae_per_file.values())
        c.dbic_val = delta_bic(ref.validation_errors.mae_per_file, aug_val.mae_per_file,
                               effective_counts(val, c.params), p, ref.validation_floors)
    struct_aug = structured_energy(judge, c.params, ref.noise)
    c.structure_explained = (1.0 - struct_aug / ref.structured_energy
                             if ref.structured_energy > 0 else 0.0)
    reasons = []
    if not c.dbic_fit < DBIC_THRESHOLD:
        reasons.append(f'fit dBIC {c.dbic_fit:.1f} not below {DBIC_THRESHOLD:g}')
    if val is not None:
        if not c.dbic_val < DBIC_THRESHOLD:
            reasons.append(f'validation dBIC {c.dbic_val:.1f} not below '
                           f'{DBIC_THRESHOLD:g}')
        if c.val_gain < 0.0:
            base_cost = sum(ref.validation_errors.mae_per_file.values())
            reasons.append(f'validation error rises ({1e3 * base_cost:.3g} -> '
                           f'{1e3 * c.val_cost:.3g} mA mean absolute error)')
        elif not c.val_gain >= MIN_VALIDATION_GAIN:
            reasons.append(f'validation error falls {100 * c.val_gain:.2f} %, less than '
                           f'{100 * MIN_VALIDATION_GAIN:g} %')
    if at_bound and space is not None:
        still = [n for n in fit.at_bound(space, c.params) if n in space.names
                 and (determined is None or n in determined)]
        if still:
            reasons.append('its refit keeps baseline parameters at a search bound ('
                           + ', '.join(still) + '): a misfit, not an effect')
    c.kept = not reasons
    c.reason = 'pays for its parameters on fit and validation data' if c.kept else \
        '; '.join(reasons)


@dataclass
class Structure:
    """The baseline residual's structure on the judging data (:func:`select`).

    Attributes
    ----------
    rms_a : float
        Structured RMS beyond the noise [A].
    noise_std_a : float
        Median noise of the files [A].
    ljung_box_p : float
        Smallest Ljung-Box p-value of the files.
    floor_rms_a : float
        Median resolution floor of the files [A].
    sizeable : bool
        The structured RMS exceeds :data:`STRUCTURE_FRACTION` of the noise.
    structured : bool
        Sizeable, or far from white while above the resolution floor.
    """

    rms_a: float
    noise_std_a: float
    ljung_box_p: float
    floor_rms_a: float
    sizeable: bool
    structured: bool


def _structure(ref: Reference, baseline: ValveParameters) -> Structure:
    """Structure: clearly more residual than noise, or a residual far from white -- the
    latter only when the residual is above the resolution floor (a noise-free record's
    residual of numerics is smooth, hence "not white", and means nothing)."""
    base_res = ref.judge.residuals(baseline)
    sigma = float(np.median(ref.noise))
    lb_p = min(ljung_box(r)[1] for r in base_res)
    floor_rms = float(np.median(list(ref.judge_floors.values()) or [0.0]))
    base_rms = math.sqrt(float(np.mean([np.mean(r[np.isfinite(r)] ** 2) for r in base_res])))
    sizeable = math.sqrt(ref.structured_energy) > STRUCTURE_FRACTION * sigma
    structured = sizeable or (math.isfinite(lb_p) and lb_p < WHITENESS_P
                              and base_rms > floor_rms)
    return Structure(rms_a=math.sqrt(ref.structured_energy), noise_std_a=sigma,
                     ljung_box_p=lb_p, floor_rms_a=floor_rms, sizeable=sizeable,
                     structured=structured)


@dataclass
class Verdict:
    """The answer of :func:`select` before the notes common to every answer."""

    effect: str
    confidence: str
    params: ValveParameters
    unexplained: bool
    evidence: list[str]


def _gain(c: CandidateResult) -> float:
    """The candidate's validation gain, its fit gain without validation data."""
    return c.val_gain if math.isfinite(c.val_gain) else c.fit_gain


def indistinguishable_runners_up(kept: list[CandidateResult]) -> list[CandidateResult]:
    """Runners-up the data cannot tell from the winner ``kept[0]`` (kept candidates, best
    first): a validation gain above :data:`INDISTINGUISHABLE` of the winner's, and a
    hold-out criterion within ``-DBIC_THRESHOLD`` of the winner's. A runner-up the hold-out
    data reject by strong evidence is told apart however close its gain (e.g. leakage
    inductance on a step record with Coulomb friction: 54 % against 65 % of the validation
    error, but a hold-out dBIC of -497 against -3481)."""
    best = kept[0]
    out = []
    for c in kept[1:]:
        if not _gain(c) > INDISTINGUISHABLE * _gain(best):
            continue
        if math.isfinite(c.dbic_val) and math.isfinite(best.dbic_val) \
                and c.dbic_val - best.dbic_val > -DBIC_THRESHOLD:
            continue
        out.append(c)
    return out


def _verdict_nothing_kept(ranked: list[CandidateResult], st: Structure,
                          baseline: ValveParameters) -> Verdict:
    evidence = ['no candidate effect pays for its extra parameters on both the fit and the '
                'validation data']
    if st.structured:
        evidence.append(
            f'but the baseline residual is structured ({1e3 * st.rms_a:.2f} '
            f'mA RMS beyond {1e3 * st.noise_std_a:.2f} mA noise, Ljung-Box p = '
            f'{st.ljung_box_p:.2g}): something the candidate list does not hold is at work; '
            'see the residual analysis')
    best = ranked[0] if ranked else None
    if best is not None and math.isfinite(best.val_gain):
        evidence.append(f'best candidate {best.effect}: validation error '
                        f'{100 * best.val_gain:+.2f} % ({best.reason})')
    return Verdict('none', 'low' if st.structured else 'high', baseline, st.structured,
                   evidence)


def _verdict_kept(kept: list[CandidateResult], st: Structure, baseline: ValveParameters,
                  at_bound: list[str]) -> Verdict:
    best = kept[0]
    # The share of structure explained only means something when the baseline residual
    # has structure; on a near-white residual the two criteria decide alone.
    if st.sizeable and best.structure_explained < MIN_EXPLAINED:
        return Verdict('none', 'low', baseline, st.structured, [
            f'{best.effect} lowers the validation error by {100 * best.val_gain:.1f} % '
            f'but removes only {100 * best.structure_explained:.0f} % of the residual '
            'structure: not claimed; the residual points to an effect outside the '
            'candidate list'])
    evidence = []
    close = indistinguishable_runners_up(kept)
    weak = not st.sizeable or best.structure_explained < HIGH_CONFIDENCE_EXPLAINED
    confidence = 'medium' if weak else 'high'
    if close:
        confidence = 'low'
        evidence.append(
            'the data cannot separate ' + ' and '.join(
                [best.effect] + [c.effect for c in close]) + ': '
            + ', '.join(f'{c.effect} gains {100 * _gain(c):.1f} %' for c in [best] + close)
            + f' (within {100 * (1 - INDISTINGUISHABLE):.0f} %); confidence low')
    if at_bound:
        confidence = 'low' if confidence == 'low' else 'medium'
        evidence.append('the baseline had parameters at a search bound ('
                        + ', '.join(at_bound) + '); the augmented model brings them '
                        'inside, so the claim stands, with at most medium confidence')
    if not st.sizeable:
        evidence.append('the baseline residual is hardly above the noise: the effect '
                        'is small and the hold-out gain is the main evidence')
    evidence.append(
        f'{best.effect} lowers the validation error by {100 * best.val_gain:.1f} % '
        f'(fit {100 * best.fit_gain:.1f} %), dBIC fit {best.dbic_fit:.0f}, '
        f'validation {best.dbic_val:.0f}, and removes '
        f'{100 * best.structure_explained:.0f} % of the residual structure')
    if len(kept) > 1:
        evidence.append(f'runner-up {kept[1].effect}: validation '
                        f'{100 * kept[1].val_gain:.1f} %')
    return Verdict(best.effect, confidence, best.params,
                   st.sizeable and best.structure_explained < FULLY_EXPLAINED, evidence)


def select(candidates: list[CandidateResult], fit: FitData, val: FitData | None,
           baseline: ValveParameters, *, baseline_at_bound: list[str] | None = None,
           space: ParameterSpace | None = None,
           determined: Collection[str] | None = None) -> Diagnosis:
    """Apply the keep rule (module notes) and decide the diagnosis.

    Parameters
    ----------
    candidates : list of CandidateResult
        The candidates, refitted or not (``params`` set on the refitted ones).
    fit, val : FitData
        Fit and validation data (``val`` None: the fit criterion alone).
    baseline : ValveParameters
        The baseline optimum.
    baseline_at_bound : list of str, optional
        Baseline parameters at a search bound that the data determine (a misfit).
    space : ParameterSpace, optional
        The baseline space (to tell whether a refit keeps them at the bound).
    determined : collection of str, optional
        Baseline parameters the data determine (narrow intervals): only these, at a
        search bound in a candidate's refit, mark the refit a misfit (default: all).

    Returns
    -------
    Diagnosis
        ``candidates`` ranked by gain, best first.
    """
    at_bound = list(baseline_at_bound or [])
    ref = _reference(fit, val, baseline)
    for c in candidates:
        if not c.refitted or c.params is None:
            c.reason = c.reason or 'not refitted (signature too weak)'
            continue
        _judge_candidate(c, ref, fit, val, at_bound, space, determined)
    ranked = sorted(candidates, key=lambda c: -(c.val_gain if math.isfinite(c.val_gain)
                                                else c.fit_gain if math.isfinite(c.fit_gain)
                                                else -math.inf))
    kept = [c for c in ranked if c.kept]
    st = _structure(ref, baseline)
    numbers: dict[str, object] = {
        'baseline_validation_structured_rms_a': st.rms_a,
        'rule': (f'keep if dBIC(fit) < {DBIC_THRESHOLD:g} and dBIC(validation) < '
                 f'{DBIC_THRESHOLD:g} and validation MAE falls >= '
                 f'{100 * MIN_VALIDATION_GAIN:g} %; claim if it also removes >= '
                 f'{100 * MIN_EXPLAINED:g} % of the validation residual energy beyond noise'),
        'resolution_floor_a': st.floor_rms_a,
        'baseline_ljung_box_p_min': st.ljung_box_p,
        'baseline_noise_std_a': st.noise_std_a,
        'judged_on': 'validation' if val is not None else 'fit',
    }
    v = (_verdict_kept(kept, st, baseline, at_bound) if kept
         else _verdict_nothing_kept(ranked, st, baseline))
    if at_bound and v.effect == 'none':
        v.evidence.append('baseline parameters at a search bound (' + ', '.join(at_bound)
                          + '): the baseline misfits; its residual is not read as a missing '
                          'effect')
        v.confidence, v.unexplained = 'low', True
    if not any(_has_release(m) for m in fit.measurements + (val.measurements if val else [])):
        v.evidence.append('no file switches the voltage off after the valve opened: without a '
                          'closing stroke coulomb_friction acts exactly like a larger spring '
                          'pre-tension (delta + F_c/k) and cannot be detected')
    numbers['baseline_at_search_bound'] = at_bound
    indist = []
    if v.effect != 'none':
        indist = [c.effect for c in indistinguishable_runners_up(kept)]
        numbers['indistinguishable_from'] = indist
    return Diagnosis(effect=v.effect, confidence=v.confidence, candidates=ranked,
                     evidence=v.evidence, numbers=numbers, params=v.params,
                     unexplained_structure=bool(v.unexplained),
                     kept_effects=[v.effect] if v.effect != 'none' else [],
                     indistinguishable=indist, judge=ref.judge,
                     base_mae={'noise': ref.noise, 'struct_base': ref.structured_energy})


def describe_remaining(diag: Diagnosis, augmented: object) -> None:
    """After the claimed effect: how much structure is left (the augmented model's
    residual analysis); a claim that leaves much of it is lowered to confidence low."""
    rep = augmented.residual_validation or augmented.residual_fit
    sigma = rep.noise_std_a
    left = rep.structured_rms_a
    ratio = left / sigma if sigma > 0 else math.inf
    diag.remaining = {'structured_rms_a': left, 'noise_std_a': sigma,
                      'structured_over_noise': ratio, 'white': rep.white,
                      'dominant_phase': rep.dominant_phase,
                      'on': 'validation' if augmented.residual_validation else 'fit'}
    text = (f'after {" + ".join(diag.kept_effects)}: {1e3 * left:.2f} mA of structured '
            f'residual left against {1e3 * sigma:.2f} mA noise ({ratio:.2f} x noise, '
            f'{"white" if rep.white else "not white"}, mostly {rep.dominant_phase})')
    diag.evidence.append(text)
    if ratio > REMAINING_STRUCTURE and diag.confidence != 'low':
        diag.confidence = 'low'
        diag.unexplained_structure = True
        diag.evidence.append('structure beyond the noise remains after the claimed effect: '
                             'something else (maybe outside the candidate list) is at work; '
                             'confidence low')


def second_effect(diag: Diagnosis, space: ParameterSpace, fit: FitData, val: FitData | None,
                  settings: SearchSettings, say: Callable[[str], None]) -> None:
    """Try the best other kept candidate on top of the claimed effect; keep both when the
    pair pays for the extra parameters under the same two criteria."""
    others = [c for c in diag.candidates if c.kept and c.effect != diag.effect]
    if not others:
        return
    other = others[0]
    ext = effect_space(space, diag.effect, at=diag.params)
    one_fit = place(fit, diag.params).errors(diag.params)
    p = len(other.fields)
    floors = resolution_floors(fit)

    def fit_dbic(params: ValveParameters) -> float:
        # samples counted in the model under test, as select() counts them; each model on
        # its own main PWM grids
        data = place(fit, params)
        return delta_bic(one_fit.mae_per_file, data.errors(params).mae_per_file,
                         effective_counts(data, params), p, floors)
    p2 = refit_effect(ext, place(fit, diag.params).serial(), diag.params, other.effect,
                      settings, screen=fit_dbic).params
    # The pair is judged against the same refit with the second effect switched off: a
    # refit moves the claimed effect's parameters too, and that further optimisation of
    # the one-effect model is no evidence for the second effect.
    p1 = _without_effect(p2, other.effect)
    p1_fit = place(fit, p1).errors(p1)
    if sum(p1_fit.mae_per_file.values()) < sum(one_fit.mae_per_file.values()):
        say(f'second effect {other.effect}: the refit also improves the {diag.effect} '
            f'model with {other.effect} switched off; the pair is judged against that')
        diag.params, one_fit = p1, p1_fit
    dfit = fit_dbic(p2)
    dval = math.nan
    gain_val = math.nan
    if val is not None:
        val2 = place(val, p2)
        counts_val = effective_counts(val2, p2)
        one_val, two_val = place(val, diag.params).errors(diag.params), val2.errors(p2)
        dval = delta_bic(one_val.mae_per_file, two_val.mae_per_file, counts_val, p,
                         resolution_floors(val))
        gain_val = 1.0 - sum(two_val.mae_per_file.values()) / sum(
            one_val.mae_per_file.values())
    val_ok = val is None or (dval < DBIC_THRESHOLD and gain_val >= MIN_VALIDATION_GAIN)
    ok = dfit < DBIC_THRESHOLD and val_ok
    diag.second = {'effect': other.effect, 'delta_bic_fit': dfit,
                   'delta_bic_validation': dval,
                   'validation_error_reduction_pct': 100.0 * gain_val
                   if math.isfinite(gain_val) else None,
                   'kept': bool(ok),
                   'parameters': {f: getattr(p2, f) for f in other.fields}}
    say(f'second effect {other.effect} on top of {diag.effect}: dBIC fit {dfit:.1f}, '
        f'validation {dval:.1f} -> {"kept" if ok else "not kept"}')
    if ok:
        diag.kept_effects.append(other.effect)
        diag.params = p2
        diag.evidence.append(
            f'a second listed effect also pays for its parameters on top of {diag.effect}: '
            f'{other.effect} (dBIC fit {dfit:.0f}, validation {dval:.0f}, validation error '
            f'{100 * gain_val:+.1f} %); both are kept in the augmented model')
    else:
        diag.evidence.append(
            f'second effect tried on top of {diag.effect}: {other.effect} does not pay for '
            f'its parameters again (dBIC fit {dfit:.1f}, validation {dval:.1f})')


def _without_effect(params: ValveParameters, effect: str) -> ValveParameters:
    """``params`` with ``effect`` switched off (its neutral values), all else kept."""
    return params.replace(**EFFECTS[effect].neutral)


#: A structured baseline misfit at least this many times the noise that no candidate
#: explains is stated as the model not describing the record (:func:`describe_misfit`).
MISFIT_OVER_NOISE = 3.0
#: Fewest at-rest samples of a file the noise of the statement is estimated from.
_MIN_REST_SAMPLES = 20
_PHASE_WORDS = {'peak_phase': 'the peak phase', 'hold': 'the hold',
                'voltage_on': 'the voltage-on phase', 'release': 'the release',
                'at_rest': 'the coil at rest'}


def _statement_noise(data: FitData, residual_noise: list[float]) -> tuple[float, str]:
    """The noise [A] the misfit is measured against, and where it comes from: the measured
    current while the coil is at rest, anywhere in the record (the measurement's own noise;
    a misfit inflates the estimate from the residual's first differences), else the
    residual's; at least the resolution floor."""
    floor = float(np.median(list(resolution_floors(data).values()) or [0.0]))
    vals = []
    for m in data.measurements:
        # the whole record, also outside the compared part: its noise is the same there
        rest = drive_phase_masks(m)['at_rest'] & np.isfinite(m.current_a)
        if int(rest.sum()) >= _MIN_REST_SAMPLES:
            vals.append(noise_std(m.current_a[rest]))
    if vals:
        return max(float(np.median(vals)), floor), 'the current at rest'
    return max(float(np.median(residual_noise)), floor), 'the baseline residual'


@dataclass
class StructuredMisfit:
    """A model's residual beyond the noise on some data (:func:`structured_misfit`).

    Attributes
    ----------
    structured_a : float
        RMS of the residual beyond the noise, ``sqrt(max(mean(r^2) - sigma^2, 0))`` [A].
    noise_a : float
        The noise it is measured against [A].
    noise_from : str
        Where the noise comes from, in words.
    residuals : list of ndarray
        The residual of each file [A].
    """

    structured_a: float
    noise_a: float
    noise_from: str
    residuals: list

    @property
    def over_noise(self) -> float:
        """The structured RMS in units of the noise (inf without noise)."""
        return self.structured_a / self.noise_a if self.noise_a > 0.0 else math.inf

    @property
    def beyond_noise(self) -> bool:
        """At least :data:`MISFIT_OVER_NOISE` times the noise: the model does not describe
        the data."""
        return self.noise_a > 0.0 and self.structured_a >= MISFIT_OVER_NOISE * self.noise_a


def structured_misfit(data: FitData, params: ValveParameters,
                      residual_noise: Sequence[float]) -> StructuredMisfit:
    """The residual of ``params`` on ``data`` beyond the noise: the noise read from the
    current at rest (else ``residual_noise`` [A] per file), the RMS of the compared
    residual with the noise's variance taken out."""
    sigma, source = _statement_noise(data, list(residual_noise) or [0.0])
    res = data.residuals(params)
    sq = np.concatenate([r[v & np.isfinite(r)] ** 2 for r, v in zip(res, data.valid)])
    structured = math.sqrt(max(float(np.mean(sq)) - sigma ** 2, 0.0)) if sq.size else 0.0
    return StructuredMisfit(structured, sigma, source, res)


#: Through a drive electronics' form the data chose, an effect is claimed only where the
#: baseline's structured residual on the judged data is at least this many times the
#: noise: forms that 1 kHz interval means cannot tell apart (a PI chopper and a hysteresis
#: band, slow decay through 0 V or a diode) leave structure of their own, which an effect
#: would absorb; on the test-data generator's forms the chosen form leaves 0.5-1.2 times
#: the noise (benchmarks/results/ident_choose_forms.md), so twice the noise keeps a margin
#: and still names an effect at three times the noise (:func:`withdraw_below_form_error`).
CLAIM_THROUGH_CHOSEN_FORM_OVER_NOISE = 2.0


def _judged_structure(diag: Diagnosis, baseline: ValveParameters) -> StructuredMisfit:
    """The baseline's structured misfit on the data the selection judged on, against the
    noise the selection read there (:func:`structured_misfit`)."""
    return structured_misfit(diag.judge, baseline, (diag.base_mae or {}).get('noise') or [0.0])


def withdraw_below_form_error(diag: Diagnosis, baseline: ValveParameters) -> bool:
    """Withdraw the claimed effect of a record fitted through a form the data chose when
    the structure it explains is below :data:`CLAIM_THROUGH_CHOSEN_FORM_OVER_NOISE` times
    the noise, or when the data cannot tell it from another effect (its indistinguishable
    runners-up): unlike effects that explain the structure about equally point to a misfit
    of the chosen form, which each absorbs in part. The answer becomes ``none`` (low) and
    the first evidence says why. True when withdrawn."""
    data = diag.judge
    if diag.effect == 'none' or data is None:
        return False
    size = _judged_structure(diag, baseline)
    if diag.indistinguishable:
        text = (f'{diag.effect} cannot be told apart from '
                f'{" or ".join(diag.indistinguishable)} by these data: unlike effects that '
                'explain the structure about equally, through a drive electronics\' form the '
                'data chose, point to a misfit of that form, which each absorbs in part; not '
                'claimed (answer none)')
    elif size.over_noise >= CLAIM_THROUGH_CHOSEN_FORM_OVER_NOISE:
        return False
    else:
        text = (f'{diag.effect} would explain structure of {1e3 * size.structured_a:.2g} mA '
                f'RMS in the baseline residual, {size.over_noise:.2g} x the noise of '
                f'{1e3 * size.noise_a:.2g} mA (from {size.noise_from}), below the '
                f'{CLAIM_THROUGH_CHOSEN_FORM_OVER_NOISE:g} x that an effect needs through a '
                'drive electronics\' form the data chose: forms these data cannot tell apart '
                'leave that much of their own; not claimed (answer none)')
    diag.numbers['withdrawn_effect'] = diag.effect
    for c in diag.candidates:
        if c.kept:
            c.kept, c.reason = False, 'withdrawn: structure below the chosen form\'s own'
    diag.effect, diag.confidence = 'none', 'low'
    diag.kept_effects, diag.indistinguishable = [], []
    diag.params = baseline
    diag.evidence.insert(0, text)
    return True


def describe_misfit(diag: Diagnosis, baseline: ValveParameters) -> None:
    """State a baseline misfit that no candidate explains, when it is well above the noise.

    With the answer ``none`` and a structured baseline residual on the judging data (the
    validation data, else the fit data) of at least :data:`MISFIT_OVER_NOISE` times the
    noise, the model (valve or drive electronics) does not describe the record: its size
    (structured RMS [A], times the noise) and where in the drive cycle it sits (share of
    the misfit energy per phase of :func:`~.residuals.drive_phase_masks`) are set as
    ``diag.misfit``, stated as the first evidence, and the confidence is low.
    """
    data = diag.judge
    if diag.effect != 'none' or not diag.unexplained_structure or data is None:
        return
    size = _judged_structure(diag, baseline)
    sigma, source, structured = size.noise_a, size.noise_from, size.structured_a
    if not size.beyond_noise:
        return
    energy = {}
    for m, r, v in zip(data.measurements, size.residuals, data.valid):
        for name, mask in drive_phase_masks(m).items():
            sel = mask & v & np.isfinite(r)
            energy[name] = energy.get(name, 0.0) + max(
                float(np.sum(r[sel] ** 2)) - int(sel.sum()) * sigma ** 2, 0.0)
    total = sum(energy.values()) or 1.0
    share = {k: e / total for k, e in sorted(energy.items(), key=lambda kv: -kv[1]) if e > 0}
    where = next(iter(share), 'at_rest')
    parts = [f'{100 * f:.0f} % in {_PHASE_WORDS[k]}' for k, f in share.items() if f >= 0.1]
    on = diag.numbers.get('judged_on', 'judged')
    text = (f'the model (valve or electronics) does not describe this record: the baseline '
            f'misses the {on} data by {1e3 * structured:.3g} mA RMS of structure '
            f'({structured / sigma:.0f} x the noise of {1e3 * sigma:.2g} mA, from {source}), '
            f'{", ".join(parts) or "spread over the cycle"} of it; no listed effect explains '
            'it: a form of the valve or of its drive electronics the model lacks, not an '
            'effect the data name (answer none: no effect claimed)')
    diag.misfit = {'statement': text, 'structured_rms_a': structured, 'noise_std_a': sigma,
                   'noise_from': source, 'over_noise': structured / sigma, 'on': on,
                   'where': where, 'where_text': f'{_PHASE_WORDS[where]} '
                   f'({100 * share.get(where, 0.0):.0f} % of it)',
                   'phase_share_of_misfit': share}
    diag.evidence.insert(0, text)
    diag.confidence = 'low'
