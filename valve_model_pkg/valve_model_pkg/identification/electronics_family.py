"""The drive electronics' form chosen by the data: peak end x hold x release.

A record through drive electronics the user does not describe (no ``--electronics``) is
fitted through each of a few complete forms of :class:`~valve_model_pkg.model.ElectronicsConfig`,
and the data choose one, as they choose an effect:

1. **A valve per release** (:func:`valve_under`): the release shapes the current most
   (a freewheel diode against a capacitor pulse: 100 mA and more), and a flexible release
   (a capacitor's voltage and decay time) absorbs a wrong valve that a release without
   constants (a freewheel diode) cannot: so each release option's constants are searched
   at the valve's start values (:func:`release_start`), and the valve is searched
   locally under the prior form with that release (the release that fits best there
   first, the others after the screen of the parts, under its best peak end).
2. **Screens.** (a) :func:`screen_parts`: each part's options (peak end: dip, dip and
   rise, current threshold, timer; hold: PI chopper with slow or fast decay, hysteresis
   band with 0 V, diode or fast decay, open-loop PWM; release: capacitor charged while
   high or during the peak only, Zener clamp, freewheel diode) in turn, the other parts
   at the prior form with the release that fits best at the start values, at that
   release's valve, each option's constants searched (:data:`PART_EFFORT`). (b)
   :func:`screen_forms`: every peak end x hold under each release at that release's
   valve (4 x 6 x 4 = 96 forms), each form's constants searched briefly
   (:data:`SCREEN_EFFORT`). The parts interact (a current-threshold peak end and an
   open-loop PWM hold pay off only together, and with the freewheel diode: each alone
   around the prior form fits worse than the prior form), which (a) cannot see; (a)'s
   longer search finds a hysteresis hold's narrow valley, which (b)'s misses. When (a)
   ranks a peak end other than the prior form's first, (b) runs also at the valves
   searched again under that peak end (:func:`valve_under`), each form's better screen
   kept: the peak end decides when the full supply stops, so it shapes the stroke as
   much as the release does, and a valve searched under a wrong one can lie so far from
   the record's that no form fits there (a current-threshold peak end, an open-loop PWM
   hold and a freewheel diode: 32 mA search-window error at the valve searched under the
   prior's dip peak end, 11 mA at the valve searched under a current threshold); but (a)
   can rank wrongly, and then only the prior's valves reach the record's form.
3. **Complete forms** (:func:`fit_forms`): the :data:`KEEP_PER_PART` best options of each
   part of (a) combined, the :data:`KEPT_FORMS` best forms of (b), the prior form
   (the paper's driver) and the form in force at the valve's start values (chosen again
   at a baseline search's optimum: the form that optimum was found through, at that
   valve; the valves of step 1 move away from it under the prior form's parts), each
   form's constants searched with the valve held; the
   :data:`FINALISTS` best, the best form with each kept option, and the prior form
   always, then search the valve locally and their constants again.
4. **Choice** (:func:`choose_form`), as an effect is selected against the baseline: the
   prior form stays unless another finalist beats it on the whole fit window by
   ``dBIC`` below ``DBIC_THRESHOLD`` (:func:`.criteria.delta_bic`, each form's constants
   counted as its parameters) and on the hold-out data by a fall of the mean absolute
   error of at least :data:`~.criteria.MIN_VALIDATION_GAIN`; among those that do, the ones
   without a constant at its search bound (a sign of misfit: a capacitor at 60 V standing
   in for a Zener clamp) go first, and the lowest hold-out error is chosen. A finalist
   whose hold-out ``|dBIC|`` against the chosen one is below ``-DBIC_THRESHOLD`` (no strong
   evidence either way) and whose hold-out error is within
   :data:`~.criteria.MIN_VALIDATION_GAIN` of it cannot be told apart from it by these
   data: the report says so and names it; when such a form has no constant at a bound
   where the chosen one has (a capacitor at 1 V standing in for a freewheel diode), or as
   few and fewer constants (a Zener clamp against a capacitor pulse), it is chosen
   instead.

The valve parameters of the forms are local searches: enough to rank forms whose misfit is
milliamperes to tens of milliamperes; the pipeline's baseline search (global stage,
simplices, polish) then runs through the chosen form.
"""
from __future__ import annotations

import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..model import ElectronicsConfig
from ..model.parameters import ValveParameters
from .criteria import DBIC_THRESHOLD, MIN_VALIDATION_GAIN, delta_bic, effective_counts
from .criteria import resolution_floors
from .drive import AT_BOUND_FRACTION, DRIVE_BOUNDS, form_choices, form_constants
from .drive import DriveFit, search_constants
from .problem import ParameterBound
from .problem import FitData, ParameterSpace, unit_objective
from .search import SearchSettings, direct_search

__all__ = ['PEAK_OPTIONS', 'HOLD_OPTIONS', 'RELEASE_OPTIONS', 'FamilyChoice', 'FormFit',
           'describe_form', 'select_family', 'release_start', 'valve_under', 'screen_forms',
           'screen_parts', 'fit_forms', 'choose_form']

#: Options of each part, as the fields of ElectronicsConfig they set.
PEAK_OPTIONS: tuple[dict[str, str], ...] = tuple(
    {'peak_end': p} for p in ('dip', 'dip_rise', 'threshold', 'timer'))
HOLD_OPTIONS: tuple[dict[str, str], ...] = (
    {'hold': 'pi', 'hold_decay': 'freewheel'}, {'hold': 'pi', 'hold_decay': 'fast'},
    {'hold': 'hysteresis', 'hold_decay': 'freewheel'},
    {'hold': 'hysteresis', 'hold_decay': 'diode'},
    {'hold': 'hysteresis', 'hold_decay': 'fast'},
    {'hold': 'pwm', 'hold_decay': 'freewheel'})
RELEASE_OPTIONS: tuple[dict[str, str], ...] = tuple(
    {'release': r} for r in ('capacitor', 'capacitor_peak', 'zener', 'diode'))
PARTS = {'peak_end': PEAK_OPTIONS, 'hold': HOLD_OPTIONS, 'release': RELEASE_OPTIONS}
#: Options of each part kept from the screen around the best form (2 x 2 x 2 forms).
KEEP_PER_PART = 2
#: Best forms of the screen of every peak end x hold whose constants are searched further.
KEPT_FORMS = 3
#: Complete forms compared on the whole fit window and the hold-out data.
FINALISTS = 3
#: Nelder-Mead iterations: a release's constants before its valve search, constants of
#: each form in the screen of every peak end x hold, in the screen of each part around
#: its best form, constants of a kept form and a finalist's.
RELEASE_EFFORT = 30
SCREEN_EFFORT = 5
PART_EFFORT = 30
FORM_EFFORT = 50
VALVE_ITERATIONS = 100

_PEAK_WORDS = {'dip': 'dip', 'dip_rise': 'dip_rise', 'threshold': 'current-threshold',
               'timer': 'timer'}
_HOLD_WORDS = {'pi': 'PI hold', 'hysteresis': 'hysteresis hold', 'pwm': 'open-loop PWM hold'}
_DECAY_WORDS = {'freewheel': 'slow decay', 'diode': 'slow (diode) decay', 'fast': 'fast decay'}
_RELEASE_WORDS = {'capacitor': 'capacitor release', 'capacitor_peak':
                  'capacitor (peak-charged) release', 'zener': 'Zener clamp release',
                  'diode': 'freewheel diode release'}


def describe_form(cfg: ElectronicsConfig) -> str:
    """The form in words: 'dip_rise peak end, PI hold with fast decay, capacitor
    (peak-charged) release'."""
    if not cfg.current_control:
        hold = 'no peak and hold (full supply while the main PWM is high)'
    else:
        hold = (f'{_PEAK_WORDS[cfg.peak_end]} peak end, {_HOLD_WORDS[cfg.hold]} with '
                f'{_DECAY_WORDS[cfg.hold_decay]}')
    release = _RELEASE_WORDS[cfg.release] if cfg.negative_voltage else 'no release pulse'
    return f'{hold}, {release}'


def describe_constants(cfg: ElectronicsConfig) -> str:
    """The form's constants that show in the current (and its settings chosen from a few
    values), as ``name = value`` in words."""
    return ', '.join(f'{n} = {getattr(cfg, n):.4g}'
                     for n in form_constants(cfg) + form_choices(cfg))


@dataclass
class FormFit:
    """One complete form fitted on the search window, and on the fit/hold-out data.

    Attributes
    ----------
    electronics : ElectronicsConfig
        The form with its searched constants.
    params : ValveParameters
        The valve after the local search through it.
    search_cost : float
        Mean absolute error on the search window [A].
    fit_mae, val_mae : dict
        Mean absolute error of each file [A] (finalists only).
    fit_rmse_a, val_rmse_a : float
        RMSE on the fit and hold-out data [A] (finalists only).
    dbic_fit, dbic_val : float
        dBIC against the chosen form (finalists only).
    refined : bool
        A finalist: the valve searched through it too.
    prior : bool
        The prior form (the paper's driver), which the others must beat.
    """

    electronics: ElectronicsConfig
    params: ValveParameters
    search_cost: float
    fit_mae: dict[str, float] = field(default_factory=dict)
    val_mae: dict[str, float] = field(default_factory=dict)
    fit_rmse_a: float = math.nan
    val_rmse_a: float = math.nan
    dbic_fit: float = math.nan
    dbic_val: float = math.nan
    refined: bool = False
    prior: bool = False

    @property
    def name(self) -> str:
        return describe_form(self.electronics)

    @property
    def n_constants(self) -> int:
        """The form's constants and its settings chosen from a few values."""
        return len(form_constants(self.electronics)) + len(form_choices(self.electronics))

    @property
    def at_bound(self) -> list[str]:
        """The form's constants at a search bound (a sign of misfit)."""
        out = []
        for n in form_constants(self.electronics):
            u = ParameterBound(n, *DRIVE_BOUNDS[n]).to_unit(getattr(self.electronics, n))
            if u <= AT_BOUND_FRACTION or u >= 1.0 - AT_BOUND_FRACTION:
                out.append(n)
        return out

    def to_json(self) -> dict[str, object]:
        return {'form': self.name, 'constants': {n: getattr(self.electronics, n)
                                                 for n in form_constants(self.electronics)},
                'search_cost_a': self.search_cost, 'fit_rmse_a': self.fit_rmse_a,
                'validation_rmse_a': self.val_rmse_a, 'delta_bic_fit': self.dbic_fit,
                'delta_bic_validation': self.dbic_val, 'at_search_bound': self.at_bound,
                'prior': self.prior}


@dataclass
class FamilyChoice:
    """The form the data chose, the forms it was compared with, and what they say.

    Attributes
    ----------
    chosen : FormFit
        The chosen form.
    screen : dict
        Per part, (option in words, search-window cost [A]) of each option, best first.
    forms : list of FormFit
        The complete forms fitted, best search-window cost first.
    indistinguishable : list of str
        Forms the data cannot tell from the chosen one.
    statement : str
        The choice in one sentence.
    """

    chosen: FormFit
    screen: dict[str, list[tuple[str, float]]]
    forms: list[FormFit]
    indistinguishable: list[str]
    statement: str

    def to_json(self) -> dict[str, object]:
        return {'chosen': self.chosen.to_json(), 'statement': self.statement,
                'cannot_tell_from': self.indistinguishable,
                'screen': {k: [{'option': o, 'search_cost_a': c} for o, c in v]
                           for k, v in self.screen.items()},
                'forms': [f.to_json() for f in self.forms]}


def _option_words(part: str, option: dict[str, str]) -> str:
    if part == 'peak_end':
        return _PEAK_WORDS[option['peak_end']] + ' peak end'
    if part == 'hold':
        return f'{_HOLD_WORDS[option["hold"]]} with {_DECAY_WORDS[option["hold_decay"]]}'
    return _RELEASE_WORDS[option['release']]


def _pool_map(fn, items: list, workers: int) -> list:
    if workers <= 1 or len(items) <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(workers, len(items))) as pool:
        return list(pool.map(fn, items))


def _view(data: FitData, cfg: ElectronicsConfig) -> FitData:
    """A serial view of ``data`` through ``cfg`` (one thread per view)."""
    v = data.serial()
    v.electronics = cfg
    v.workers = 1
    return v


def _valve_search(data: FitData, space: ParameterSpace, starts: list[ValveParameters],
                  cfg: ElectronicsConfig) -> tuple[ValveParameters, float]:
    """Local search of the valve through ``cfg`` from ``starts`` (one simplex each)."""
    fun = unit_objective(space, _view(data, cfg))
    u0 = np.vstack([space.to_unit(p) for p in starts])
    res = direct_search(fun, u0, SearchSettings(
        global_samples=0, starts=len(starts), max_iterations=VALVE_ITERATIONS,
        initial_step=0.08, restarts=0, stall_iterations=30), label='form valve')
    own = fun(u0)
    k = int(np.argmin(own))
    if own[k] <= res.cost:
        return starts[k], float(own[k])
    return space.params(res.u), float(res.cost)


@dataclass
class ValveStart:
    """A release's valve: the valve searched locally through the prior form with that
    release, and the form with the release's constants searched.

    Attributes
    ----------
    params : ValveParameters
        The valve after the local search.
    base : ElectronicsConfig
        The prior form with this release and its constants.
    start_cost : float
        Search-window cost at the valve's start values, before the valve search [A].
    cost : float
        Search-window cost after the valve search [A].
    """

    params: ValveParameters
    base: ElectronicsConfig
    start_cost: float
    cost: float


def release_start(data: FitData, start: ValveParameters, base: ElectronicsConfig,
                  workers: int) -> list[DriveFit]:
    """Per release option, ``base`` with that release and its constants searched at the
    valve ``start`` (:data:`RELEASE_EFFORT`), with their cost [A]; in the order of
    :data:`RELEASE_OPTIONS`."""
    def one(opt: dict[str, str]) -> DriveFit:
        cfg = base.replace(**opt)
        return search_constants(_view(data, cfg), start, cfg, RELEASE_EFFORT)
    return _pool_map(one, list(RELEASE_OPTIONS), workers)


def _valve_for(data: FitData, space: ParameterSpace, starts: list[ValveParameters],
               drive: DriveFit) -> ValveStart:
    params, cost = _valve_search(data, space, starts, drive.electronics)
    return ValveStart(params, drive.electronics, float(drive.cost), cost)


def valve_under(data: FitData, space: ParameterSpace, starts: list[ValveParameters],
                base: ElectronicsConfig, workers: int,
                drives: list[DriveFit] | None = None,
                known: ValveStart | None = None) -> list[ValveStart]:
    """Per release option, its constants at the valve's start values (``drives``, else
    :func:`release_start`), then the valve searched locally under that form (module
    notes, step 1; ``known``: one of them already searched); in the order of
    :data:`RELEASE_OPTIONS`."""
    if drives is None:
        drives = release_start(data, starts[0], base, workers)

    def one(drive: DriveFit) -> ValveStart:
        if known is not None and drive.electronics == known.base:
            return known
        return _valve_for(data, space, starts, drive)
    return _pool_map(one, drives, workers)


def screen_forms(data: FitData, starts: list[ValveStart], workers: int) -> list[FormFit]:
    """Every peak end x hold under each release, at that release's valve and with its
    release constants, the form's constants searched (:data:`SCREEN_EFFORT`); best first."""
    jobs = [(s, s.base.replace(**p, **h)) for s in starts
            for p, h in itertools.product(PEAK_OPTIONS, HOLD_OPTIONS)]

    def one(job: tuple[ValveStart, ElectronicsConfig]) -> FormFit:
        s, cfg = job
        drive = search_constants(_view(data, cfg), s.params, cfg, SCREEN_EFFORT)
        return FormFit(drive.electronics, s.params, float(drive.cost))
    return sorted(_pool_map(one, jobs, workers), key=lambda f: f.search_cost)


def _best_per_form(forms: list[FormFit]) -> list[FormFit]:
    """Of forms screened at several valves, each form's best (``forms`` best first)."""
    out: list[FormFit] = []
    for f in forms:
        if not any(_same_form(f.electronics, g.electronics) for g in out):
            out.append(f)
    return out


def _has(f: FormFit, option: dict[str, str]) -> bool:
    return all(getattr(f.electronics, k) == v for k, v in option.items())


def screen_words(forms: list[FormFit]) -> dict[str, list[tuple[str, float]]]:
    """Per part, each option in words with the lowest screen cost of a form with it [A],
    best first."""
    out: dict[str, list[tuple[str, float]]] = {}
    for part, opts in PARTS.items():
        costs = [(_option_words(part, o), min(
            (f.search_cost for f in forms if _has(f, o)),
            default=math.inf)) for o in opts]
        out[part] = sorted(costs, key=lambda x: x[1])
    return out


def screen_parts(data: FitData, centre: FormFit, workers: int
                 ) -> dict[str, list[tuple[dict[str, str], float]]]:
    """Each part's options, the other parts at the ``centre`` form: the form's constants
    searched (:data:`PART_EFFORT`) with the valve at ``centre``'s; per part the options
    with their cost [A], best first."""
    jobs = [(part, opt) for part, opts in PARTS.items() for opt in opts]

    def one(job: tuple[str, dict[str, str]]) -> float:
        cfg = centre.electronics.replace(**job[1])
        return search_constants(_view(data, cfg), centre.params, cfg, PART_EFFORT).cost
    costs = _pool_map(one, jobs, workers)
    out: dict[str, list[tuple[dict[str, str], float]]] = {p: [] for p in PARTS}
    for (part, opt), c in zip(jobs, costs):
        out[part].append((opt, float(c)))
    for part in out:
        out[part].sort(key=lambda x: x[1])
    return out


def _constants_only(data: FitData, f: FormFit, grid: bool) -> FormFit:
    """The form's constants searched further, the valve held at ``f``'s (``grid``: a
    hysteresis hold's clock, band and set point first on a grid); a form of the screen
    starts from its constants, a combination of options from the hold read off the data."""
    screened = math.isfinite(f.search_cost)
    drive = search_constants(_view(data, f.electronics), f.params, f.electronics,
                             FORM_EFFORT, grid=grid, read_hold=not screened)
    if drive.cost < f.search_cost:
        return FormFit(drive.electronics, f.params, float(drive.cost))
    return FormFit(f.electronics, f.params, f.search_cost)


def _refine_form(data: FitData, space: ParameterSpace, f: FormFit, grid: bool) -> FormFit:
    """The valve searched locally through ``f``'s form, then its constants again."""
    params, cost = _valve_search(data, space, [f.params], f.electronics)
    drive = search_constants(_view(data, f.electronics), params, f.electronics,
                             FORM_EFFORT // 2, grid=grid)
    if drive.cost < cost:
        return FormFit(drive.electronics, params, float(drive.cost), refined=True,
                       prior=f.prior)
    return FormFit(f.electronics, params, cost, refined=True, prior=f.prior)


def _same_form(a: ElectronicsConfig, b: ElectronicsConfig) -> bool:
    return all(getattr(a, k) == getattr(b, k) for k in ('peak_end', 'hold', 'hold_decay',
                                                        'release'))


def fit_forms(data: FitData, space: ParameterSpace, centre: FormFit,
              parts: dict[str, list[tuple[dict[str, str], float]]],
              screened: list[FormFit], prior: ElectronicsConfig, workers: int,
              grid: bool = True, incumbent: FormFit | None = None) -> list[FormFit]:
    """The complete forms of the :data:`KEEP_PER_PART` best options of each part around
    ``centre`` (at its valve) and the ``prior`` form there, and the :data:`KEPT_FORMS` best
    forms of the screen of every peak end x hold (at their release's valve) and the
    ``incumbent`` (the form in force at the valve the choice starts from), their
    constants searched further (a form found both ways: the lower cost); the
    :data:`FINALISTS` best, the best form with each kept option (so that two releases,
    say, are compared with the valve refitted through each) and the ``prior`` form
    refined (:func:`_refine_form`). Finalists first (by their cost), then the others."""
    kept = [[o for o, _ in parts[p][:KEEP_PER_PART]] for p in PARTS]
    forms = []
    for combo in itertools.product(*kept):
        changes: dict[str, str] = {}
        for c in combo:
            changes.update(c)
        forms.append(centre.electronics.replace(**changes))
    if not any(_same_form(c, prior) for c in forms):
        forms.append(centre.electronics.replace(**{k: getattr(prior, k) for k in (
            'peak_end', 'hold', 'hold_decay', 'release')}))
    todo = [FormFit(c, centre.params, math.inf) for c in forms] + screened[:KEPT_FORMS]
    if incumbent is not None:
        todo.append(incumbent)
    fits = _best_per_form(sorted(_pool_map(lambda f: _constants_only(data, f, grid), todo,
                                           workers), key=lambda f: f.search_cost))
    for f in fits:
        f.prior = _same_form(f.electronics, prior)
    chosen = fits[:FINALISTS] + [f for f in fits[FINALISTS:] if f.prior]
    for opts in kept:
        for opt in opts:
            best = next(f for f in fits if _has(f, opt))
            if best not in chosen:
                chosen.append(best)
    top = _pool_map(lambda f: _refine_form(data, space, f, grid), chosen, workers)
    return sorted(top, key=lambda f: f.search_cost) + [f for f in fits if f not in chosen]


def _judge(f: FormFit, fit: FitData, val: FitData | None) -> None:
    """Errors of ``f`` on the fit and hold-out data."""
    v = _view(fit, f.electronics)
    e = v.errors(f.params)
    f.fit_mae, f.fit_rmse_a = e.mae_per_file, e.rmse
    if val is not None:
        e = _view(val, f.electronics).errors(f.params)
        f.val_mae, f.val_rmse_a = e.mae_per_file, e.rmse


def _dbic(data: FitData, ref: FormFit, other: FormFit, ref_mae: dict[str, float],
          other_mae: dict[str, float]) -> float:
    """dBIC of ``other`` against ``ref`` on ``data`` (the forms' constants counted)."""
    counts = effective_counts(_view(data, ref.electronics), ref.params)
    return delta_bic(ref_mae, other_mae, counts, other.n_constants - ref.n_constants,
                     resolution_floors(data))


def _val_gain(ref: FormFit, f: FormFit) -> float:
    """Relative fall of the hold-out mean absolute error from ``ref`` to ``f``."""
    return 1.0 - sum(f.val_mae.values()) / max(sum(ref.val_mae.values()), 1e-30)


def _beats(fit: FitData, val: FitData | None, ref: FormFit, f: FormFit) -> bool:
    """``f`` is strongly better than ``ref``: fit dBIC and hold-out error (module notes)."""
    if _dbic(fit, ref, f, ref.fit_mae, f.fit_mae) >= DBIC_THRESHOLD:
        return False
    return val is None or _val_gain(ref, f) >= MIN_VALIDATION_GAIN


def _cannot_tell(fit: FitData, val: FitData | None, chosen: FormFit, f: FormFit) -> bool:
    """The data hold no strong evidence between ``f`` and ``chosen`` (module notes)."""
    f.dbic_fit = _dbic(fit, chosen, f, chosen.fit_mae, f.fit_mae)
    if val is None:
        return f is not chosen and abs(f.dbic_fit) < -DBIC_THRESHOLD
    f.dbic_val = _dbic(val, chosen, f, chosen.val_mae, f.val_mae)
    return (f is not chosen and abs(f.dbic_val) < -DBIC_THRESHOLD
            and abs(_val_gain(f, chosen)) < MIN_VALIDATION_GAIN)


def _plainness(f: FormFit) -> tuple[bool, int]:
    """Order of preference among forms the data cannot tell apart: none of its constants
    at a bound (a capacitor at 1 V standing in for a diode), then fewer constants."""
    return bool(f.at_bound), f.n_constants


def choose_form(forms: list[FormFit], fit: FitData, val: FitData | None, workers: int
                ) -> tuple[FormFit, list[str], str]:
    """The chosen form among the finalists, the forms the data cannot tell from it, and
    the choice in words (module notes, step 4)."""
    finalists = [f for f in forms if f.refined]
    _pool_map(lambda f: _judge(f, fit, val), finalists, workers)
    ref = next((f for f in finalists if f.prior),
               min(finalists, key=lambda f: sum(f.fit_mae.values())))
    better = [f for f in finalists if f is not ref and _beats(fit, val, ref, f)]
    pool = [f for f in better if not f.at_bound] or better
    where = 'hold-out' if val is not None else 'fit'
    if pool:
        chosen = min(pool, key=lambda f: sum((f.val_mae if val is not None
                                              else f.fit_mae).values()))
    else:
        chosen = ref
    same = [f for f in finalists if _cannot_tell(fit, val, chosen, f)]
    plainer = [f for f in same if _plainness(f) < _plainness(chosen)]
    first = chosen
    if plainer:
        # the data cannot tell them apart: no constant at a bound, then fewer constants
        chosen = min(plainer, key=lambda f: (_plainness(f), sum(f.fit_mae.values())))
        same = [f for f in finalists if _cannot_tell(fit, val, chosen, f)]
    err = chosen.val_rmse_a if val is not None else chosen.fit_rmse_a
    text = (f'drive electronics chosen by the data: {chosen.name}; constants '
            f'{describe_constants(chosen.electronics)} ({where} RMSE {1e3 * err:.3g} mA; '
            f'{len(forms)} complete forms fitted, {len(finalists)} compared on the fit and '
            f'{where} data')
    if not pool:
        whom = ('the prior one (the paper\'s driver)' if ref.prior else
                'the one of lowest fit-window error')
        text += (f'; no form beat {whom} by dBIC below {DBIC_THRESHOLD:g} on the fit data '
                 f'and {100 * MIN_VALIDATION_GAIN:g} % less {where} error')
    if chosen is not first:
        worse = ('a constant at a search bound' if first.at_bound and not chosen.at_bound
                 else 'more constants')
        text += (f'; {first.name} has {worse}, and the data cannot tell this form from it: '
                 'this one is taken')
    elif not pool:
        text += ': it is kept'
    text += ')'
    if same:
        text += ('; the data cannot tell it from: ' + '; '.join(f.name for f in same)
                 + f' (|dBIC| below {-DBIC_THRESHOLD:g} and {where} error within '
                 f'{100 * MIN_VALIDATION_GAIN:g} %)')
    return chosen, [f.name for f in same], text


def _incumbent(search: FitData, params: ValveParameters) -> FormFit:
    """The form in force on ``search`` (the one the valve ``params`` was searched
    through) at that valve, with its search-window cost."""
    cost = _view(search, search.electronics).cost(params.to_vector()[None, :])[0]
    return FormFit(search.electronics, params, float(cost))


def select_family(search: FitData, fit: FitData, val: FitData | None, space: ParameterSpace,
                  starts: list[ValveParameters], workers: int,
                  base: ElectronicsConfig = ElectronicsConfig(), grid: bool = True
                  ) -> FamilyChoice:
    """Screen the parts, fit the complete forms of the best options, choose one.

    Parameters
    ----------
    search : FitData
        The search window's data (screen and complete forms).
    fit, val : FitData
        The whole fit window and the hold-out data (the finalists' comparison).
    space : ParameterSpace
        The valve's search space.
    starts : list of ValveParameters
        Start values of the valve (the first holds it during the screen).
    workers : int
        Python threads (one form or option per thread).
    base : ElectronicsConfig
        The prior form (the paper's driver), which another form must beat; the other
        parts' forms during the screen.
    grid : bool
        A hysteresis hold's clock, band and set point placed on a grid before their local
        search in the complete forms (:func:`.drive.hysteresis_grid`; worth it at a valve
        near the record's, where the ripple's phase is what is left).
    """
    drives = release_start(search, starts[0], base, workers)
    first = _valve_for(search, space, starts, min(drives, key=lambda d: d.cost))
    centre = FormFit(first.base, first.params, first.cost)
    parts = screen_parts(search, centre, workers)
    valves = valve_under(search, space, starts, base, workers, drives, first)
    peak = parts['peak_end'][0][0]
    if not all(getattr(base, k) == v for k, v in peak.items()):
        # The valve searched under the prior's peak end can be far from the record's when
        # the record's peak ends otherwise, and the one searched under the part screen's
        # best peak end can be far when the screen ranks wrongly: both are screened.
        valves += valve_under(search, space, starts, base.replace(**peak), workers)
    screened = _best_per_form(screen_forms(search, valves, workers))
    forms = fit_forms(search, space, centre, parts, screened, base, workers, grid,
                      _incumbent(search, starts[0]))
    chosen, same, text = choose_form(forms, fit, val, workers)
    words = screen_words(screened)
    return FamilyChoice(chosen, words, forms, same, text)
