"""The whole loop: baseline fit, residual study, candidate effects, refits, selection.

:func:`identify` is what ``valve_identify`` runs; it returns an :class:`Identification`
that :mod:`.report` writes out. It runs these stages, each a function returning a named
result:

1. :func:`read_inputs` (:class:`Inputs`): the records (read from their files if given as
   paths), the known parameters with every effect switched off;
2. :func:`prepare_data` (:class:`Prepared`): the PWM period grids placed, hold-out and
   windows, the fit, validation and search data, the parameter space;
   :func:`settle_electronics` (:class:`ElectronicsSettled`): the drive electronics' form
   of records through the electronics, given (``--electronics``) or chosen by the data
   (:mod:`.electronics_family`; chosen again by :func:`reselect_electronics` after the
   baseline search);
3. :func:`search_baseline` (:class:`~.search.SearchResult`): the direct search of the
   baseline parameters;
4. :func:`alternate_electronics` (:class:`ElectronicsRounds`): the drive electronics and
   the valve searched in turn (records through the electronics only); stages 2-4 run in
   :func:`search_route`, which lets the data choose the route when the records carry both
   the mean coil voltage and the PWM commands (:class:`RouteStart`);
5. :func:`polish_baseline` (:class:`BaselineFit`): local polishes on the fit window until
   they no longer pay, the electronics' last fit;
6. :func:`analyse_baseline` (:class:`BaselineAnalysis`): errors, residuals, intervals,
   parameters at a search bound;
7. :func:`diagnose` (:class:`DiagnosisOutcome`): signatures, refits of the candidates,
   the selection, a second effect, the augmented model, an effect outside the list.
"""
from __future__ import annotations

import logging
import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Callable, Sequence, Union

import numpy as np

from ..errors import MeasurementFormatError, ParameterError
from ..interface import TOPIC_STATE
from ..model import ElectronicsConfig, batch_threads, load_electronics
from ..model.parameters import EFFECTS, ValveParameters
from .criteria import (DBIC_THRESHOLD, delta_bic, effective_counts, noise_per_file,
                       resolution_floors)
from .diagnosis import (
    SCREEN_DBIC, CandidateResult, Diagnosis, RefitResult, StructuredMisfit, describe_misfit,
    describe_remaining, refit_effect, score_signatures, second_effect, select, slow_effect,
    structured_misfit, withdraw_below_form_error,
)
from .drive import DriveReport, fit_drive
from .electronics_family import FamilyChoice, describe_form, select_family
from .mean_voltage import (ROUTE_AUTO, ROUTE_BARE_COIL, ROUTE_CHOICES, ROUTE_ELECTRONICS,
                           ROUTE_MEAN_VOLTAGE, Route, RouteScreen, check_mean_voltage,
                           choose_route, hold_error, settle_route,
                           through_drive_counterparts)
from .measurement import (Measurement, check_current_response, hold_out, window,
                          with_current_lsb)
from .phase import (PHASE_RESOLUTION_S, best_phase, phase_free, phase_shifts, place, placed,
                    shift_measurement, shiftable)
from .pwm_compare import pwm_comparison
from .problem import (
    SEARCH_RATE_HZ, ErrorFigures, FitData, ParameterSpace, baseline_space, coarse_data,
    effect_space, start_point, unit_objective,
)
from .residuals import ResidualReport, analyse_residuals
from .search import SearchResult, SearchSettings, direct_search
from .topic_map import parse_topic_map
from .sensitivity import SensitivityReport, analyse_sensitivity, noise_std

__all__ = ['IdentifySettings', 'Identification', 'identify', 'Stage', 'Convergence',
           'BASELINE_EFFORT', 'QUICK_BASELINE_EFFORT', 'REFIT_EFFORT', 'QUICK_REFIT_EFFORT']

#: A record: a Measurement, or the path of a file or bag directory to read.
Record = Union[Measurement, str, os.PathLike]
Say = Callable[[str], None]
_LOG = logging.getLogger(__name__)

#: Effort of the baseline search (global stage + multi-start), and of ``quick``.
BASELINE_EFFORT = SearchSettings(global_samples=256, starts=6, max_iterations=400)
QUICK_BASELINE_EFFORT = SearchSettings(global_samples=128, starts=4, max_iterations=250)
#: Effort of each candidate's refit (local, from the baseline optimum), and of ``quick``.
REFIT_EFFORT = SearchSettings(global_samples=0, starts=5, max_iterations=500,
                              initial_step=0.1, restarts=3)
QUICK_REFIT_EFFORT = SearchSettings(global_samples=0, starts=5, max_iterations=300,
                                    initial_step=0.1, restarts=2)


@dataclass(frozen=True)
class IdentifySettings:
    """Everything :func:`identify` can be told: what, from what, with which effort.

    ``valve_identify`` parses its arguments into these (the option in brackets); a
    Python user passes them to :func:`identify` directly.

    Attributes
    ----------
    params_file : str or None
        Known parameters (Table 1, the orifice) as a YAML file (``--params``); None: the
        packaged set. A ``base`` given to :func:`identify` takes precedence.
    allow_implausible : bool
        Accept parameter values outside their plausible ranges with a warning
        (``--allow-implausible``).
    topic : str
        Valve state topic in bag records (``--topic``).
    valve : str or None
        ``frame_id`` of the valve in multi-valve bags (``--valve``).
    topic_map : tuple of str
        ``ROLE=TOPIC[.FIELD]`` entries reading bags from a user's own topics instead of
        the valve state topic (``--map``, :func:`.topic_map.parse_topic_map`); empty: the
        suite's topics.
    diagnose : bool
        False stops after the baseline fit, the paper's Section 4 only (``--no-diagnosis``).
    effects : tuple of str or None
        Candidate effects (names of the model's registry, ``--effects``); None: every one.
    quick : bool
        Smaller search effort for tests and previews (``--quick``): the baseline search
        and the refits of step records take :data:`QUICK_BASELINE_EFFORT` and
        :data:`QUICK_REFIT_EFFORT`.
    seed : int
        Seed of the baseline search's global stage (Sobol scrambling, ``--seed``).
    threads : int or None
        Python threads of the identification: refits, drive electronics candidates,
        small batches (``--threads``); 1 also keeps the kernel's batches on the calling
        thread. None: one per CPU.
    baseline, refit : SearchSettings or None
        Explicit efforts of the baseline search and of each refit (step records); None:
        by ``quick``.
    max_refits : int
        How many candidates (ranked by signature score) are refitted at most.
    refit_top_k : int or None
        Candidates refitted: the ``refit_top_k`` best signature scores (plus the partner
        of a pair the signatures hardly separate, :data:`REFIT_PAIRS`); None refits all
        (up to ``max_refits``). The others are reported as skipped, with their score.
    operation_search_window_s : float
        The search stages (global stage, simplices, drive electronics, other start points,
        refits) run on at most this much of each record through the electronics [s]; the
        polish, the intervals and the selection use the whole fit window.
    electronics_rounds : int
        Alternations of drive electronics and valve search.
    final_drive_effort : int
        Nelder-Mead iterations of the drive electronics' last fit (on the fit window, from
        the search window's values).
    refit_polish_iterations : int
        Nelder-Mead iterations of a refit's polish on the fit window (records through the
        electronics, refits that paid on the search window).
    operation_baseline, operation_refit : SearchSettings
        Effort of the baseline search when the fit data run the drive electronics, and of
        the refits of operational records (:attr:`Prepared.operational`: through the
        electronics or around them; each simulated second costs ~20 ms there, against
        ~1 ms for a 40 ms step): fewer simplices and iterations; the polish on the fit
        window shows convergence all the same.
    operation_local_iterations : int
        Nelder-Mead iterations of the local searches around the search's optimum on
        records through the electronics (valve re-search after the electronics, other
        start points, each polish round on the fit window).
    operation_fit_window_s, operation_validation_window_s : float
        Records through the electronics are fitted on at most this much of their length
        after their discarded start [s], and validated on at most that much (the
        simulation of a chopped record costs about 25 ms per simulated second; a second
        holds 20-100 PWM periods).
    hold_out_fraction : float
        Share of a single record through the electronics held out for validation when no
        validation file is given (the last part).
    electronics : ElectronicsConfig, path or None
        The drive electronics of records through the electronics (``--electronics``): an
        :class:`~valve_model_pkg.model.ElectronicsConfig` or the path of its description
        file (YAML, :func:`~valve_model_pkg.model.load_electronics`, read here). None:
        the paper's driver's form with fitted constants, or the form chosen by the data
        (:attr:`choose_electronics`, :mod:`.electronics_family`).
    electronics_fixed : bool
        With :attr:`electronics`: take its constants as they are (default), or as start
        values of their fit within bounds (False, ``--fit-electronics``). The form is
        the given one either way.
    choose_electronics : bool or None
        Without :attr:`electronics`: choose the form by the data (True,
        ``--choose-electronics always``; it adds about half of a quick run), or use the
        paper's driver's form and fit its constants (False, ``never``). None (``auto``,
        the default): the paper's driver's form, and the form chosen by the data when
        the final model through it still misses the record by at least
        :data:`~.diagnosis.MISFIT_OVER_NOISE` times the noise (:func:`electronics_misfit`;
        the identification runs again through the chosen form, and the run that misses
        less goes on).
    route : str
        How records through the drive electronics are fitted (``--route``): ``'auto'``
        lets the data choose when they carry both the mean coil voltage and the PWM
        commands (:func:`search_route`); ``'mean-voltage'`` or ``'electronics'`` forces
        that route (:func:`.mean_voltage.choose_route`).
    """

    params_file: str | None = None
    allow_implausible: bool = False
    topic: str = '/' + TOPIC_STATE
    valve: str | None = None
    topic_map: tuple[str, ...] = ()
    diagnose: bool = True
    effects: tuple[str, ...] | None = None
    quick: bool = False
    seed: int = 0
    threads: int | None = None
    baseline: SearchSettings | None = None
    refit: SearchSettings | None = None
    max_refits: int = len(EFFECTS)
    refit_top_k: int | None = 4
    operation_search_window_s: float = 0.4
    electronics_rounds: int = 2
    final_drive_effort: int = 40
    refit_polish_iterations: int = 150
    operation_baseline: SearchSettings = SearchSettings(global_samples=256, starts=4,
                                                        max_iterations=300,
                                                        stall_iterations=40)
    operation_refit: SearchSettings = SearchSettings(global_samples=0, starts=5,
                                                     max_iterations=120, initial_step=0.1,
                                                     restarts=1, stall_iterations=25)
    operation_local_iterations: int = 150
    operation_fit_window_s: float = 1.0
    operation_validation_window_s: float = 3.0
    hold_out_fraction: float = 0.3
    electronics: ElectronicsConfig | str | os.PathLike | None = None
    electronics_fixed: bool = True
    choose_electronics: bool | None = None
    route: str = ROUTE_AUTO

    def __post_init__(self) -> None:
        if self.electronics is not None and not isinstance(self.electronics,
                                                           ElectronicsConfig):
            object.__setattr__(self, 'electronics', load_electronics(self.electronics))
        if self.route not in ROUTE_CHOICES:
            raise ParameterError(f'route: {self.route!r} is not one of '
                                 f'{", ".join(ROUTE_CHOICES)}')
        unknown = [e for e in self.effects or () if e not in EFFECTS]
        if unknown:
            raise ParameterError(f'effects: {unknown[0]!r} is not an effect of the model; '
                                 f'choose from {", ".join(EFFECTS)}')
        if self.threads is not None and self.threads < 1:
            raise ParameterError(f'threads: {self.threads} is not at least 1')
        try:
            parse_topic_map(self.topic_map)
        except ValueError as err:
            raise ParameterError(f'topic_map: {err}') from None

    def baseline_effort(self, through_electronics: bool) -> SearchSettings:
        """The baseline search's effort (with :attr:`seed`)."""
        if through_electronics:
            s = self.operation_baseline
        else:
            s = self.baseline or (QUICK_BASELINE_EFFORT if self.quick else BASELINE_EFFORT)
        return replace(s, seed=self.seed) if self.seed else s

    def refit_effort(self, operational: bool) -> SearchSettings:
        """Each refit's effort: operational records' (:attr:`Prepared.operational`) or step
        records'."""
        if operational:
            return self.operation_refit
        return self.refit or (QUICK_REFIT_EFFORT if self.quick else REFIT_EFFORT)

    @property
    def workers(self) -> int:
        """Python threads of the identification (:attr:`threads`, else the kernel's batch
        threads: ``NUMBA_NUM_THREADS``, else one per CPU this process may run on)."""
        return self.threads or batch_threads()


#: Candidates whose signatures look alike on a current record (the friction force and
#: the leakage inductance both delay and soften the stroke's dip): refitting one of a
#: pair refits the other, so the selection can say when the data cannot separate them.
REFIT_PAIRS: tuple[tuple[str, str], ...] = (('coulomb_friction', 'leakage_inductance'),)
#: A parameter at a search bound whose 95 % interval is below this [%] is a misfit sign.
MISFIT_CI95_PCT = 50.0
#: The baseline counts as converged when a local polish (fresh simplices around the best
#: point) lowers the cost by less than this fraction of the noise's mean absolute error.
CONVERGENCE_FRACTION = 0.02
#: ... or by less than this relative amount (noise-free data).
CONVERGENCE_RELATIVE = 1e-3
#: Relative tolerance of the polishes' simplices (:class:`~.search.SearchSettings`): far
#: below the convergence tolerance (at least 1e-3 of the cost), so a polish that stops on
#: it has not left a gain that would matter.
POLISH_TOLERANCE = 1e-4


@dataclass
class Stage:
    """Parameters and errors of one model (baseline or augmented)."""

    params: ValveParameters
    fit: ErrorFigures
    validation: ErrorFigures | None
    residual_fit: ResidualReport
    residual_validation: ResidualReport | None
    sensitivity: SensitivityReport | None = None


@dataclass
class Convergence:
    """Evidence that the baseline search converged before any effect is considered."""

    search_cost_a: float
    polish_costs_a: list[float]
    final_cost_a: float
    noise_mae_a: float
    tolerance_a: float
    converged: bool
    statement: str

    def to_json(self) -> dict[str, object]:
        return dict(self.__dict__)


@dataclass
class Identification:
    """Everything the report needs."""

    fit_files: list[Measurement]
    val_files: list[Measurement]
    baseline: Stage
    augmented: Stage
    diagnosis: Diagnosis | None
    start: ValveParameters
    space: ParameterSpace
    timings_s: dict[str, float] = field(default_factory=dict)
    simulations: int = 0
    sim_fit: dict[str, list] = field(default_factory=dict)
    sim_val: dict[str, list] = field(default_factory=dict)
    convergence: Convergence | None = None
    drive: DriveReport | None = None
    at_bound: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    route: str = ROUTE_BARE_COIL
    family: FamilyChoice | None = None
    electronics_source: str = ''
    route_screen: RouteScreen | None = None
    electronics_trigger: dict[str, object] | None = None


def _lap(say: Say, what: str, t0: float) -> float:
    """Seconds since ``t0``, said as a progress line."""
    dt = time.perf_counter() - t0
    say(f'time: {what} {dt:.1f} s')
    return dt


# --- stage 1: the inputs ---------------------------------------------------------------

@dataclass
class Inputs:
    """The records and the known parameters (:func:`read_inputs`)."""

    fit: list[Measurement]
    validation: list[Measurement]
    base: ValveParameters


def _read(records: Sequence[Record], settings: IdentifySettings) -> list[Measurement]:
    """``records`` as Measurements; paths are read (files and bags in the order given)."""
    from .readers import read_measurements
    mapping = parse_topic_map(settings.topic_map) or None
    out: list[Measurement] = []
    for r in records:
        if isinstance(r, Measurement):
            out.append(with_current_lsb(r))
        else:
            out += read_measurements([r], topic=settings.topic, valve=settings.valve,
                                     mapping=mapping)
    return out


def read_inputs(fit: Sequence[Record], validate: Sequence[Record],
                settings: IdentifySettings, base: ValveParameters | None, say: Say) -> Inputs:
    """Read the records and the known parameters; every effect switched off in the latter.

    Raises
    ------
    MeasurementFormatError
        A record cannot be read, lacks its supply pressure, or its current does not
        respond to its coil voltage (:func:`.measurement.check_current_response`, at the
        scale V/R of the parameter set's coil resistance).
    ParameterError
        The parameter file is refused.
    """
    from ..model.parameters import load_parameters
    # The parameter file first: a refused file costs no reading of the records.
    if base is None:
        base = load_parameters(settings.params_file,
                               allow_implausible=settings.allow_implausible)
    fit_list = [pwm_comparison(m) for m in _read(fit, settings)]
    val_list = [pwm_comparison(m) for m in _read(validate, settings)]
    for m in fit_list + val_list:
        if m.supply_pressure_pa is None:
            raise MeasurementFormatError(
                m.source, None, 'metadata lacks supply_pressure_pa (gauge, Pa)')
        check_current_response(m, base.coil_resistance_ohm)
    for m in fit_list + val_list:
        for note in m.notes:
            say(f'{m.name}: {note}')
    # Effects a parameter file may switch on are switched off for the baseline: the
    # baseline is the paper's model, the loop decides on effects.
    neutral = {}
    for spec in EFFECTS.values():
        neutral.update(spec.neutral)
    return Inputs(fit_list, val_list, base.replace(**neutral))


def route_inputs(inputs: Inputs, settings: IdentifySettings, say: Say
                 ) -> tuple[Inputs, Route]:
    """The records as the valve is fitted: around the drive electronics through their
    measured mean coil voltage when every record through them carries it
    (:func:`.mean_voltage.choose_route`, ``settings.route``); returns the inputs and the
    route (with its rival when the data are to choose, :func:`search_route`)."""
    route = choose_route(inputs.fit, inputs.validation, settings.route)
    say(route.note)
    return Inputs(route.fit, route.validation, inputs.base), route


# --- stage 2: the data -----------------------------------------------------------------

def refine_phases(files: list[Measurement], params: ValveParameters, say: Say,
                  electronics=None) -> list[Measurement]:
    """Place each record's main PWM period grid where the current says, within the range
    its command changes allow (1 kHz telemetry bounds a period start to 1 ms)."""
    out = []
    for m in files:
        if not phase_free(m):
            out.append(m)
            continue
        lo, hi = m.drive.phase_range_s
        best = best_phase(m, params, electronics, parallel=True)
        new = shift_measurement(m, best)
        say(f'{m.name}: main PWM period grid placed {1e3 * best:+.3f} ms from the middle of '
            f'the range its command changes allow ({1e3 * lo:+.3f}..{1e3 * hi:+.3f} ms)')
        out.append(replace(new, notes=m.notes + (
            f'main PWM phase refined from the current: first period start '
            f'{1e3 * new.drive.period_starts_s[0]:.3f} ms',)))
    return out


@dataclass
class PreparedFiles:
    """Fit and validation records after hold-out and windows (:func:`prepare_files`)."""

    fit: list[Measurement]
    validation: list[Measurement]
    notes: list[str]


def prepare_files(fit_files: Sequence[Measurement], val_files: Sequence[Measurement],
                  settings: IdentifySettings) -> PreparedFiles:
    """Hold-out of a single operational record, windows of long ones; notes in words."""
    fit, val = list(fit_files), list(val_files)
    notes = []
    if len(fit) == 1 and not val and fit[0].in_service:
        f, v = hold_out(fit[0], settings.hold_out_fraction)
        fit, val = [f], [v]
        notes.append(f'one record and no validation file: the last '
                     f'{100 * settings.hold_out_fraction:.0f} % of {fit[0].name} (from '
                     f'{v.held_out_from_s:.3g} s) is held out for validation')
    fit = [window(m, settings.operation_fit_window_s) if m.in_service else m
           for m in fit]
    val = [window(m, settings.operation_validation_window_s) if m.in_service else m
           for m in val]
    return PreparedFiles(fit, val, notes)


def search_data(fit_list: list[Measurement], fit: FitData, settings: IdentifySettings
                ) -> tuple[FitData, str]:
    """The data the search stages run on: records through the electronics cut to the
    search window (``fit`` itself when nothing is cut), and a note in words."""
    span = settings.operation_search_window_s
    cut = [window(m, span) if m.in_service else m for m in fit_list]
    if all(a is b for a, b in zip(cut, fit_list)):
        return fit, ''
    data = FitData(cut)
    names = [a.name for a, b in zip(cut, fit_list) if a is not b]
    return data, (f'search stages (global stage, simplices, drive electronics, other start '
                  f'points, effect refits) on the first {span:g} s of the compared part of '
                  f'{", ".join(names)}; the polish, intervals and selection on the whole fit '
                  'and validation windows')


@dataclass
class Prepared:
    """The data of the fit (:func:`prepare_data`).

    Attributes
    ----------
    fit, validation : FitData
        Fit and validation data (``validation`` None without validation records).
    search : FitData
        The data the search stages run on (``fit`` itself unless records through the
        electronics are cut to the search window).
    search_note : str
        Says what the search window is ('' when ``search`` is ``fit``).
    space : ParameterSpace
        The baseline parameters' search space.
    start : ValveParameters
        The search's start point.
    notes : list of str
        Notes for the report.
    coarse : FitData
        ``search`` with fast step records compared at :data:`~.problem.SEARCH_RATE_HZ`
        (:func:`~.problem.coarse_data`): the baseline search and the refits' profiles run
        on it, the polishes, intervals and selection on every sample (``search`` itself
        when no record is that fast).
    """

    fit: FitData
    validation: FitData | None
    search: FitData
    search_note: str
    space: ParameterSpace
    start: ValveParameters
    notes: list[str]
    electronics_fixed: bool = False
    coarse: FitData | None = None

    def __post_init__(self) -> None:
        if self.coarse is None:
            self.coarse = self.search

    @property
    def through_electronics(self) -> bool:
        return self.fit.through_electronics

    @property
    def operational(self) -> bool:
        """True for records searched on a window of the fit window (operational records,
        through the electronics or around them): each refit then has the operational
        effort (:meth:`IdentifySettings.refit_effort`), its profiles judged early."""
        return self.through_electronics or self.search is not self.fit

    def use_electronics(self, electronics) -> None:
        """Set the identified drive electronics on every data set."""
        for d in (self.fit, self.search, self.coarse, self.validation):
            if d is not None:
                d.electronics = electronics

    def place_phases(self, params: ValveParameters) -> list[str]:
        """Place every record's main PWM grid again where ``params``' current fits best
        (:mod:`.phase`): the fit, search and coarse data share the fit records' grids, the
        validation records have their own. Returns what moved, in words."""
        moved = []
        shifts = phase_shifts(self.fit, params) if shiftable(self.fit) else ()
        if any(abs(s) >= PHASE_RESOLUTION_S for s in shifts):
            same = self.search is self.fit
            same_coarse = self.coarse is self.search
            self.fit = placed(self.fit, shifts)
            self.search = self.fit if same else placed(self.search, shifts)
            self.coarse = self.search if same_coarse else placed(self.coarse, shifts)
            moved += [(m.name, s) for m, s in zip(self.fit.full, shifts)
                      if abs(s) >= PHASE_RESOLUTION_S]
        if self.validation is not None and shiftable(self.validation):
            v_shifts = phase_shifts(self.validation, params)
            self.validation = placed(self.validation, v_shifts)
            moved += [(m.name, s) for m, s in zip(self.validation.full, v_shifts)
                      if abs(s) >= PHASE_RESOLUTION_S]
        return [f'{name}: main PWM period grid moved {1e3 * s:+.3f} ms' for name, s in moved]


def _fit_data(files: list[Measurement], settings: IdentifySettings) -> FitData:
    data = FitData(files)
    data.workers = settings.workers
    if settings.threads == 1:
        data.parallel = False
    return data


def prepare_data(inputs: Inputs, settings: IdentifySettings, say: Say,
                 electronics: ElectronicsConfig | None = None) -> Prepared:
    """Place the PWM grids, hold out and window the records, build the data and space
    (records through the electronics run ``electronics``, default the paper's driver)."""
    fit_files = refine_phases(list(inputs.fit), inputs.base, say, electronics)
    val_files = refine_phases(list(inputs.validation), inputs.base, say, electronics)
    files = prepare_files(fit_files, val_files, settings)
    for n in files.notes:
        say(n)
    fit = _fit_data(files.fit, settings)
    val = _fit_data(files.validation, settings) if files.validation else None
    for m in fit.measurements:
        say(f'fit file {m.summary()}')
    for m in (val.measurements if val else []):
        say(f'validation file {m.summary()}')
    space = baseline_space(inputs.base)
    search, search_note = search_data(files.fit, fit, settings)
    if search is not fit:
        search.workers, search.parallel = fit.workers, fit.parallel
    notes = list(files.notes)
    if search_note:
        notes.append(search_note)
        say(search_note)
    coarse = coarse_data(search)
    if coarse is not search:
        note = (f'search stages (global stage, simplices, effect profiles) compare the step '
                f'records at {SEARCH_RATE_HZ / 1e3:g} kHz; the polishes, intervals and '
                'selection every sample')
        notes.append(note)
        say(note)
    prep = Prepared(fit, val, search, search_note, space, start_point(space), notes,
                    coarse=coarse)
    if electronics is not None:
        prep.use_electronics(electronics)
    return prep


# --- stage 2b: the drive electronics' form ----------------------------------------------

@dataclass
class ElectronicsSettled:
    """The data through the electronics' form to identify with (:func:`settle_electronics`).

    Attributes
    ----------
    prep : Prepared
        The data, through the given or chosen form.
    family : FamilyChoice or None
        The forms compared and the choice (None: given, or no record through electronics).
    source : str
        Where the form comes from, in words ('' without records through the electronics).
    paper : Prepared or None
        The data through the paper's driver when the data chose another form (the
        baseline search runs through both: :func:`search_through_the_paper`).
    """

    prep: Prepared
    family: FamilyChoice | None
    source: str
    paper: Prepared | None = None


def settle_electronics(inputs: Inputs, prep: Prepared, settings: IdentifySettings,
                       say: Say) -> ElectronicsSettled:
    """The drive electronics' form: the user's (:attr:`IdentifySettings.electronics`), the
    data's choice (:mod:`.electronics_family`), or the paper's driver's; the data prepared
    again through a chosen form (its PWM grids placed through it)."""
    given = settings.electronics
    if not prep.through_electronics:
        if given is not None:
            note = ('--electronics given, but no record runs through the drive electronics '
                    '(step records, or pwm records with their coil voltage): not used')
            say(note)
            prep.notes.append(note)
        return ElectronicsSettled(prep, None, '')
    if given is not None:
        prep.electronics_fixed = settings.electronics_fixed
        how = ('constants as given' if settings.electronics_fixed else
               'constants fitted from the given values')
        source = f'given (--electronics): {describe_form(given)}; {how}'
        say('drive electronics ' + source)
        return ElectronicsSettled(prep, None, source)
    if not settings.choose_electronics:
        source = f'the paper\'s driver: {describe_form(ElectronicsConfig())}; constants fitted'
        return ElectronicsSettled(prep, None, source)
    say('drive electronics: screening the forms (peak end x hold x release)')
    family = select_family(prep.search, prep.fit, prep.validation, prep.space,
                           [prep.start, prep.space.base], settings.workers, grid=False)
    _say_family(family, say)
    chosen = _start_electronics(family)
    new = prepare_data(inputs, settings, lambda s: None, chosen)
    new.notes.append(family.statement)
    return ElectronicsSettled(new, family, 'chosen by the data: ' + describe_form(chosen),
                              None if family.chosen.prior else prep)


def _start_electronics(family: FamilyChoice) -> ElectronicsConfig:
    """The electronics the baseline starts from: the chosen form with its constants; the
    prior form (the paper's driver) kept by the choice starts from its nominal constants,
    as without the choice (its constants searched through a locally fitted valve can hold
    the valve's global search in a poor minimum)."""
    return ElectronicsConfig() if family.chosen.prior else family.chosen.electronics


def _say_family(family: FamilyChoice, say: Say) -> None:
    for part, opts in family.screen.items():
        say(f'  screen {part}: ' + ', '.join(f'{o} {1e3 * c:.3g} mA' for o, c in opts))
    for f in family.forms:
        say(f'  form {f.name}: search-window MAE {1e3 * f.search_cost:.3g} mA')
    say(family.statement)


def reselect_electronics(prep: Prepared, settled: ElectronicsSettled, params: ValveParameters,
                         settings: IdentifySettings, say: Say) -> ElectronicsSettled:
    """The form chosen again with the valve at the baseline search's optimum (``params``):
    the first choice compared forms at a valve searched only locally, this one at the valve
    the record shows; the data keep their PWM grids."""
    say('drive electronics: the forms screened again at the baseline search\'s optimum')
    family = select_family(prep.search, prep.fit, prep.validation, prep.space, [params],
                           settings.workers)
    _say_family(family, say)
    prep.use_electronics(_start_electronics(family))
    first = settled.family.statement if settled.family else ''
    prep.notes[:] = [n for n in prep.notes if n != first] + [family.statement]
    return ElectronicsSettled(prep, family,
                              'chosen by the data: ' + describe_form(family.chosen.electronics))


# --- stages 3-5: the baseline ----------------------------------------------------------

def search_baseline(prep: Prepared, settings: IdentifySettings, say: Say) -> SearchResult:
    """Direct search of the baseline parameters on the search data."""
    space = prep.space
    say('baseline: direct search over ' + ', '.join(space.names))
    res = direct_search(unit_objective(space, prep.coarse), space.to_unit(prep.start),
                        settings.baseline_effort(prep.through_electronics),
                        progress=say, label='baseline')
    say(f'baseline: cost {res.cost:.6g} A after {res.evaluations} simulations')
    return res


def search_through_the_paper(elec: ElectronicsSettled, res: SearchResult,
                             settings: IdentifySettings, say: Say,
                             known: SearchResult | None = None
                             ) -> tuple[SearchResult, ElectronicsSettled]:
    """The baseline search again on the data through the paper's driver (nominal
    constants, ``elec.paper``) when the data chose another form at the valve's start
    values; the lower search cost goes on with its data. A form chosen at a valve far
    from the record's can hold the global search in a poor minimum that the paper's
    driver avoids; the form is chosen again at the optimum (:func:`reselect_electronics`).
    ``known``: that search, run before on the same data (not repeated)."""
    if known is None:
        say('baseline: the direct search again through the paper\'s driver')
        paper = search_baseline(elec.paper, settings, say)
    else:
        paper = known
    if paper.cost >= res.cost:
        return res, elec
    say(f'baseline: through the paper\'s driver {1e3 * paper.cost:.3g} mA against '
        f'{1e3 * res.cost:.3g} mA through the chosen form: it goes on')
    return paper, replace(elec, prep=elec.paper, paper=None)


def _two_starts(u: np.ndarray, others: np.ndarray | None) -> np.ndarray:
    """``u`` and a second start (the nearest other start point of the global stage, or a
    small offset), so that a lock-step local search keeps two cores busy."""
    if others is not None:
        far = [x for x in np.atleast_2d(others) if np.max(np.abs(x - u)) > 1e-3]
        if far:
            near = min(far, key=lambda x: float(np.max(np.abs(x - u))))
            return np.vstack([u, u + 0.25 * (near - u)])
    return np.vstack([u, np.clip(u + 0.02, 0.0, 1.0)])


@dataclass
class ElectronicsRounds:
    """The baseline after the drive electronics and the valve were searched in turn."""

    u: np.ndarray
    drive: DriveReport | None


def alternate_electronics(prep: Prepared, res: SearchResult, settings: IdentifySettings,
                          say: Say) -> ElectronicsRounds:
    """Electronics and valve alternately, both on the search window: the drive constants
    with the valve held, then the valve again under the identified electronics."""
    if not prep.through_electronics:
        return ElectronicsRounds(res.u, None)
    space, fun_s = prep.space, unit_objective(prep.space, prep.search)
    u_best, drive = res.u, None
    for _ in range(settings.electronics_rounds):
        drive = fit_drive(prep.search, space.params(u_best), fixed=prep.electronics_fixed)
        prep.use_electronics(drive.electronics)
        say('drive electronics: ' + ', '.join(f'{k} = {v:.4g}'
                                              for k, v in drive.values.items()))
        c_best = float(fun_s(u_best[None, :])[0])
        again = direct_search(fun_s, _two_starts(u_best, res.starts_u), SearchSettings(
            global_samples=0, starts=2, max_iterations=settings.operation_local_iterations,
            initial_step=0.08, restarts=1, stall_iterations=30),
            label='baseline (electronics identified)')
        if again.cost < c_best:
            u_best = again.u
    return ElectronicsRounds(u_best, drive)


@dataclass
class RouteStart:
    """The route of the valve fit and its baseline search (:func:`search_route`).

    Attributes
    ----------
    route : Route
        The route, settled.
    prep : Prepared
        The route's data.
    rounds : ElectronicsRounds
        The search's optimum (after the electronics rounds on records through them).
    screen : RouteScreen or None
        Both routes' errors when the data chose the route.
    elec : ElectronicsSettled or None
        The drive electronics' form the route's data run through (None: none settled).
    """

    route: Route
    prep: Prepared
    rounds: ElectronicsRounds
    screen: RouteScreen | None = None
    elec: ElectronicsSettled | None = None
    paper_search: SearchResult | None = None


def _route_criterion(data: FitData, params: ValveParameters, k: int, hold_out: bool
                     ) -> tuple[float, float]:
    """(RMSE [A], criterion) of ``params`` on ``data``: the criterion is the RMSE on
    hold-out records, else the BIC ``n ln(mse) + k ln(n)`` over the compared samples."""
    rmse = data.errors(params).rmse
    if hold_out or not math.isfinite(rmse):
        return rmse, rmse
    n = sum(int(v.sum()) for v in data.valid)
    return rmse, n * math.log(max(rmse, 1e-12) ** 2) + k * math.log(n)


def search_route(inputs: Inputs, route: Route, settings: IdentifySettings,
                 timings: dict[str, float], say: Say,
                 paper_search: SearchResult | None = None) -> RouteStart:
    """Stages 2-4 on the route, or on both routes when the records carry both the mean
    coil voltage and the PWM commands (``route.rival``): the data choose.

    The screen costs one global search: the baseline is searched on the mean-voltage
    route (the bare coil, cheap), the electronics route starts from that optimum
    (:func:`alternate_electronics`: the drive constants with the valve held, then the
    valve again, twice); each route's baseline is compared on the hold-out records (RMS
    error), else on the fit window (BIC, the electronics' constants counted). When the
    errors are too close to tell the routes apart (a misfit common to both dominates),
    the mean-voltage route goes on (:class:`.mean_voltage.RouteScreen`). The chosen route
    goes on; the other one's error and how well the electronics reproduce the measured
    mean voltage are stated in the route's note. ``paper_search``: the baseline search
    through the paper's driver, run before on the same data (a choice of the form compares
    with it instead of searching again); the one run here is returned as
    :attr:`RouteStart.paper_search`.
    """
    t0 = time.perf_counter()
    prep = prepare_data(inputs, settings, say, settings.electronics)
    timings['phase_grid'] = time.perf_counter() - t0
    t0 = time.perf_counter()
    elec = settle_electronics(inputs, prep, settings, say)
    prep = elec.prep
    if elec.family is not None:
        timings['electronics_family'] = _lap(say, 'electronics family', t0)
    t0 = time.perf_counter()
    res = search_baseline(prep, settings, say)
    through_paper = (res if prep.through_electronics and settings.electronics is None
                     and elec.family is None else paper_search)
    if elec.paper is not None:
        res, elec = search_through_the_paper(elec, res, settings, say, paper_search)
        prep = elec.prep
    timings['baseline_search'] = _lap(say, 'baseline search', t0)
    if elec.family is not None:
        t0 = time.perf_counter()
        elec = reselect_electronics(prep, elec, prep.space.params(res.u), settings, say)
        prep = elec.prep
        timings['electronics_family_2'] = _lap(say, 'electronics family at the baseline', t0)
    t0 = time.perf_counter()
    if route.rival is None:
        rounds = alternate_electronics(prep, res, settings, say)
        if prep.through_electronics:
            timings['electronics'] = _lap(say, 'drive electronics', t0)
        return RouteStart(route, prep, rounds, elec=elec, paper_search=through_paper)
    say('route: the records carry the mean coil voltage and the PWM commands; the '
        'electronics route starts from the mean-voltage optimum')
    rival_inputs = Inputs(route.rival.fit, route.rival.validation, inputs.base)
    rival_elec = settle_electronics(rival_inputs,
                                    prepare_data(rival_inputs, settings, say,
                                                 settings.electronics), settings, say)
    rival = rival_elec.prep
    if not rival.through_electronics:
        # only hold-out records run through the electronics: no fit record carries what
        # their constants would be fitted on, so the electronics route cannot be judged
        settled = replace(route, rival=None, note=f'{route.note}; the electronics route is '
                          'not tried: no fit record runs through the drive electronics')
        say(settled.note)
        timings['route_screen'] = _lap(say, 'route screen', t0)
        return RouteStart(settled, prep, ElectronicsRounds(res.u, None), None, elec)
    rival_rounds = alternate_electronics(rival, res, settings, say)
    hold = prep.validation is not None
    rmse, crit = {}, {}
    for name, p, u, k in ((ROUTE_MEAN_VOLTAGE, prep, res.u, 0),
                          (ROUTE_ELECTRONICS, rival, rival_rounds.u,
                           sum(rival_rounds.drive.carried.values()))):
        rmse[name], crit[name] = _route_criterion(
            p.validation if hold else p.fit, p.space.params(u), p.space.size + k, hold)
    rival_params = rival.space.params(rival_rounds.u)
    voltage = check_mean_voltage(rival.fit.full, rival_params,
                                 rival_rounds.drive.electronics)
    compared = rival.validation if hold else rival.fit
    held = hold_error(compared.full, rival_params, rival_rounds.drive.electronics)
    screen = RouteScreen(rmse, crit, 'the hold-out records' if hold else
                         'the fit window (BIC with the electronics constants counted)',
                         voltage, held)
    settled = settle_route(route, screen)
    say(settled.note)
    timings['route_screen'] = _lap(say, 'route screen', t0)
    if settled.name == ROUTE_ELECTRONICS:
        return RouteStart(settled, rival, rival_rounds, screen, rival_elec)
    return RouteStart(settled, prep, ElectronicsRounds(res.u, None), screen, elec)


@dataclass
class _OtherStarts:
    """Outcome of the simplices from other start points on the search window."""

    u: np.ndarray
    cost: float
    text: str


def _try_other_starts(space: ParameterSpace, data: FitData, check_data: FitData,
                      u: np.ndarray, cost: float, others: np.ndarray, check_label: str,
                      iterations: int) -> _OtherStarts:
    """Simplices from ``u`` and from ``others`` on ``check_data``, in lock step; their best
    point is taken when it is better on ``data`` too."""
    fun = unit_objective(space, data)
    fun_c = unit_objective(space, check_data)
    own = float(fun_c(u[None, :])[0])
    n_others = len(others)
    st = SearchSettings(global_samples=0, starts=n_others + 1, max_iterations=iterations,
                        initial_step=0.1, restarts=0, stall_iterations=30,
                        tolerance=POLISH_TOLERANCE, seed=1)
    res = direct_search(fun_c, np.vstack([u[None, :], np.atleast_2d(others)]), st,
                        label='baseline other starts')
    # The start points themselves are judged on the fit window too: where the search
    # window leaves a direction unseen (a stroke the valve does not reach there), its
    # simplices drift along it, and the start point can be the better one.
    cand = np.vstack([res.u[None, :], np.atleast_2d(others)])
    costs = fun(cand)
    j = int(np.argmin(costs))
    there = float(costs[j])
    moved = there < cost
    which = 'their best point' if j == 0 else f'other start point {j} itself'
    text = (f'; simplices from the optimum and from the {n_others} other start points '
            f'on {check_label} reached {res.cost:.4g} A there (the optimum: {own:.4g}'
            f' A); on the fit window their best point {float(costs[0]):.4g} A, the start '
            'points ' + ', '.join(f'{c:.4g}' for c in costs[1:]) + ' A'
            + (f' ({which} taken)' if moved else ' (not better: kept the optimum)'))
    return _OtherStarts(cand[j].copy() if moved else u, there if moved else cost, text)


def polish(space: ParameterSpace, data: FitData, u: np.ndarray, cost: float,
           noise_a: float, say: Say, rounds: int = 3,
           others: np.ndarray | None = None, check_data: FitData | None = None,
           check_label: str = '', iterations: int = 300) -> tuple[np.ndarray, Convergence]:
    """Polish the baseline until a fresh local search no longer pays (see Convergence).

    The first round also runs independent simplices from ``others`` (other start points:
    the measured values, the prior), in lock step: a lower cost reached from elsewhere
    means the search had stopped in a local minimum. With
    ``check_data`` (the search window of a long record) those simplices run there, and
    their best point is carried to ``data`` when it is better there too; the rounds on
    ``data`` then start from the best point (and a second start beside it, so two cores
    work).
    """
    fun = unit_objective(space, data)
    noise_mae = noise_a * math.sqrt(2.0 / math.pi) if math.isfinite(noise_a) else 0.0
    tol = max(CONVERGENCE_FRACTION * noise_mae, CONVERGENCE_RELATIVE * cost)
    costs = []
    best_u, best_c = u.copy(), cost
    converged = False
    gain = math.inf
    checked = ''
    n_others = 0 if others is None else len(others)
    if check_data is not None and n_others:
        tried = _try_other_starts(space, data, check_data, best_u, best_c, others,
                                  check_label, iterations)
        best_u, best_c, checked = tried.u, tried.cost, tried.text
        say('baseline other start points' + checked)
        others = None
    for r in range(rounds):
        starts = best_u[None, :]
        if r == 0 and others is not None and len(others):
            starts = np.vstack([best_u[None, :], np.atleast_2d(others)])
        elif check_data is not None:
            starts = _two_starts(best_u, None)
        short = iterations < 300
        st = SearchSettings(global_samples=0, starts=starts.shape[0], max_iterations=iterations,
                            initial_step=0.1 / (r + 1), restarts=1 if short else 2,
                            stall_iterations=40 if short else 60, tolerance=POLISH_TOLERANCE,
                            seed=r + 1)
        res = direct_search(fun, starts, st, label=f'baseline polish {r + 1}')
        gain = best_c - res.cost
        costs.append(float(res.cost))
        if res.cost < best_c:
            best_u, best_c = res.u.copy(), float(res.cost)
        say(f'baseline polish {r + 1}: cost {res.cost:.6g} A (gain {gain:.3g} A, tolerance '
            f'{tol:.3g} A)')
        if gain <= tol:
            converged = True
            break
    where = '' if checked else f' and from {n_others} other start points'
    statement = (f'baseline converged: local polishes from the optimum{where} lowered the '
                 f'cost (mean absolute error) from {cost:.4g} A to {best_c:.4g} A; the last '
                 f'polish gained {max(gain, 0.0):.2g} A, within '
                 f'{tol:.2g} A = max({100 * CONVERGENCE_FRACTION:g} % of the noise MAE '
                 f'{noise_mae:.3g} A, {CONVERGENCE_RELATIVE:g} of the cost)' + checked
                 if converged else
                 f'baseline NOT shown converged: {rounds} polishes still lowered the cost '
                 f'({cost:.4g} -> {best_c:.4g} A, tolerance {tol:.2g} A)' + checked)
    return best_u, Convergence(search_cost_a=cost, polish_costs_a=costs, final_cost_a=best_c,
                               noise_mae_a=noise_mae, tolerance_a=tol, converged=converged,
                               statement=statement)


@dataclass
class BaselineFit:
    """The polished baseline (:func:`polish_baseline`).

    Attributes
    ----------
    u : numpy.ndarray
        Its unit coordinates in the baseline space.
    params : ValveParameters
        Its parameters.
    convergence : Convergence
        The polishes' evidence of convergence.
    drive : DriveReport or None
        The drive electronics fitted on the fit window (records through the electronics).
    """

    u: np.ndarray
    params: ValveParameters
    convergence: Convergence
    drive: DriveReport | None


def polish_baseline(prep: Prepared, rounds: ElectronicsRounds, settings: IdentifySettings,
                    say: Say) -> BaselineFit:
    """Local polishes on the whole fit window until they no longer pay, from the search's
    optimum and from the measured values (and for records through the electronics the
    prior); then the electronics' last fit there."""
    space = prep.space
    through = prep.through_electronics
    u_best, drive = rounds.u, rounds.drive
    # The grids were placed with the start point's current; the baseline's own phase is
    # where its optimum fits (each model is judged on its own grids, :mod:`.phase`).
    moved = prep.place_phases(space.params(u_best))
    if moved:
        note = ('main PWM grids placed again at the baseline search\'s optimum (the phase '
                'is fitted with each model): ' + '; '.join(moved))
        say(note)
        prep.notes.append(note)
    fit = prep.fit
    c_best = float(unit_objective(space, fit)(u_best[None, :])[0])
    noise0 = float(np.nanmedian([noise_std(r, m.current_lsb_a) for m, r in zip(
        fit.measurements, fit.residuals(space.params(u_best)))]))
    others = [space.to_unit(prep.start)]
    if through:
        # The prior (packaged set or --params) is a start of the polish too: the refits
        # scan their effect from it (diagnosis.refit_effect), and a baseline that never
        # looked there would lose to "prior plus a little of any effect" on a valve that
        # is its prior.
        others.append(space.to_unit(space.base))
    # The global stage's other good points are not among them: the search ran a simplex
    # from each of them already.
    u_best, conv = polish(space, fit, u_best, c_best, noise0, say, others=np.array(others),
                          check_data=None if prep.search is fit else prep.search,
                          check_label=prep.search_note and f'the first '
                          f'{settings.operation_search_window_s:g} s (search window)',
                          iterations=settings.operation_local_iterations if through else 300)
    moved = prep.place_phases(space.params(u_best))
    if moved:
        fit = prep.fit
        cost = float(unit_objective(space, fit)(u_best[None, :])[0])
        conv = replace(conv, final_cost_a=cost, statement=(
            conv.statement + f'; the main PWM grids placed again at the polished optimum '
            f'({"; ".join(moved)}): cost {cost:.4g} A'))
    say(conv.statement)
    if through:
        drive = fit_drive(fit, space.params(u_best), effort=settings.final_drive_effort,
                          fixed=prep.electronics_fixed)
        prep.use_electronics(drive.electronics)
    return BaselineFit(u_best, space.params(u_best), conv, drive)


@dataclass
class EvaluatedStage:
    """A model's :class:`Stage` and its simulated currents (for the plots)."""

    stage: Stage
    current_fit: list[np.ndarray]
    current_val: list[np.ndarray]


def _residual_report(params: ValveParameters, data: FitData
                     ) -> tuple[ResidualReport, list[np.ndarray]]:
    sims = data.simulate(params.to_vector()[None, :])
    res = [np.where(v, m.current_a - c[0], np.nan)
           for m, v, (c, _) in zip(data.measurements, data.valid, sims)]
    rep = analyse_residuals(data.measurements, res, [x[0] for _, x in sims], params.stroke_m)
    return rep, [c[0] for c, _ in sims]


def evaluate_stage(params: ValveParameters, fit: FitData, val: FitData | None
                   ) -> EvaluatedStage:
    """Errors, residual analysis and simulated currents of ``params``."""
    rep_fit, cur_fit = _residual_report(params, fit)
    rep_val, cur_val, val_err = None, [], None
    if val is not None:
        rep_val, cur_val = _residual_report(params, val)
        val_err = val.errors(params)
    return EvaluatedStage(Stage(params=params, fit=fit.errors(params), validation=val_err,
                                residual_fit=rep_fit, residual_validation=rep_val),
                          cur_fit, cur_val)


@dataclass
class BaselineAnalysis:
    """The baseline's errors, residuals and intervals (:func:`analyse_baseline`).

    Attributes
    ----------
    evaluated : EvaluatedStage
        The baseline stage (with its sensitivity) and its simulated currents.
    at_bound : list of str
        Baseline parameters at a search bound.
    misfit : list of str
        Those of them the data determine (a sign of misfit).
    drive : DriveReport or None
        The drive electronics with their intervals.
    notes : list of str
        Notes for the report.
    """

    evaluated: EvaluatedStage
    at_bound: list[str]
    misfit: list[str]
    drive: DriveReport | None
    notes: list[str]

    @property
    def stage(self) -> Stage:
        return self.evaluated.stage

    @property
    def determined(self) -> list[str]:
        """Baseline parameters the data determine (95 % CI below :data:`MISFIT_CI95_PCT`):
        at a search bound, only these are a sign of misfit, in the baseline or a refit."""
        ci = self.stage.sensitivity.ci95_pct
        return [n for n, v in ci.items() if v is not None and v < MISFIT_CI95_PCT]


def analyse_baseline(prep: Prepared, base: BaselineFit, say: Say) -> BaselineAnalysis:
    """Errors, residual analysis and intervals of the baseline; the parameters at a search
    bound, read as misfit only where the data determine them."""
    fit, params = prep.fit, base.params
    at_bound = fit.at_bound(prep.space, params)
    if at_bound:
        say('baseline parameters at a search bound (misfit): ' + ', '.join(at_bound))
    ev = evaluate_stage(params, fit, prep.validation)
    ev.stage.sensitivity = analyse_sensitivity(prep.space, fit, params, at_bound=at_bound,
                                               nrmse_pct=ev.stage.fit.nrmse_pct)
    drive = base.drive
    if drive is not None:
        drive = fit_drive(fit, params, effort=0, inflation=ev.stage.sensitivity.inflation,
                          fixed=prep.electronics_fixed)
    # A bound reached along a direction the data do not see (b on a step: the damping
    # force is ~1 % of the others) is no misfit; one the data care about is.
    ci = ev.stage.sensitivity.ci95_pct
    misfit = [n for n in at_bound if ci.get(n) is not None and ci[n] < MISFIT_CI95_PCT]
    notes = []
    if at_bound:
        notes.append('at a search bound: ' + ', '.join(at_bound) + (
            '; the data determine ' + ', '.join(misfit) + ' (95 % CI below '
            f'{MISFIT_CI95_PCT:g} %): a sign of misfit' if misfit else
            '; the data hardly see them (wide intervals): not read as misfit'))
    return BaselineAnalysis(ev, at_bound, misfit, drive, notes)


# --- stage 7: the diagnosis ------------------------------------------------------------

def rank_candidates(prep: Prepared, analysis: BaselineAnalysis, settings: IdentifySettings,
                    say: Say) -> list[CandidateResult]:
    """The candidate effects ranked by their signature's correlation with the baseline
    residual, best first (:attr:`IdentifySettings.effects` only)."""
    fit = prep.fit
    params = analysis.stage.params
    residuals = [np.where(v, m.current_a - c, np.nan)
                 for m, v, c in zip(fit.measurements, fit.valid, analysis.evaluated.current_fit)]
    scores = score_signatures(prep.space, fit, params, residuals)
    order = sorted(scores, key=lambda e: -scores[e][0])
    say('signatures: ' + ', '.join(f'{e} {scores[e][0]:+.2f}' for e in order))
    return candidates_from_scores(scores, settings)


def candidates_from_scores(scores: dict[str, tuple[float, float]],
                           settings: IdentifySettings) -> list[CandidateResult]:
    """Candidates of :attr:`IdentifySettings.effects` from their signature scores
    (correlation, amplitude), best correlation first."""
    order = sorted(scores, key=lambda e: -scores[e][0])
    allowed = set(settings.effects) if settings.effects is not None else set(EFFECTS)
    return [CandidateResult(effect=eff, fields=EFFECTS[eff].fields,
                            signature_correlation=scores[eff][0],
                            signature_amplitude=scores[eff][1])
            for eff in order if eff in allowed]


def choose_refits(candidates: list[CandidateResult], settings: IdentifySettings
                  ) -> tuple[list[CandidateResult], list[tuple[CandidateResult, str]]]:
    """Candidates to refit (``candidates`` ranked by signature score, best first) and the
    skipped ones with the reason in words."""
    k = settings.refit_top_k
    limit = settings.max_refits
    if k is None or k >= len(candidates):
        chosen = list(candidates[:limit])
    else:
        chosen = list(candidates[:k])
        names = {c.effect for c in chosen}
        for a, b in REFIT_PAIRS:
            for x, y in ((a, b), (b, a)):
                if x in names and y not in names:
                    chosen += [c for c in candidates if c.effect == y]
                    names.add(y)
        chosen = [c for c in candidates if c in chosen][:max(limit, 0)]
    skipped = []
    for rank, c in enumerate(candidates, 1):
        if c in chosen:
            continue
        skipped.append((c, f'not refitted: signature score {c.signature_correlation:+.2f} '
                           f'ranked {rank} of {len(candidates)}; only the '
                           f'{min(k or limit, limit)} best (and the partner of '
                           'friction/leakage) are refitted'))
    return chosen, skipped


@dataclass
class RefitBar:
    """What a refit on a window must beat: the baseline on the data it searches.

    Attributes
    ----------
    data : FitData
        The data searched (a serial view: each refit runs in its own thread).
    cost : float
        The baseline's cost there [A].
    base_mae : dict
        The baseline's mean absolute error of each file [A].
    floors : dict
        Resolution floor of each file [A].
    """

    data: FitData
    cost: float
    base_mae: dict[str, float]
    floors: dict[str, float]


@dataclass
class RefitJob:
    """What every candidate's refit shares (:func:`refit_candidate`).

    Attributes
    ----------
    prep : Prepared
        The data and space.
    baseline : BaselineFit
        The baseline optimum.
    effort : SearchSettings
        Each refit's effort.
    bars : dict
        By "slower than the search window": the :class:`RefitBar` of the data searched
        (step records: ``False``, the fit data).
    settings : IdentifySettings
        The settings.
    timings : dict
        Receives each refit's time (``refit_<effect>``).
    say : callable
        Progress.
    """

    prep: Prepared
    baseline: BaselineFit
    effort: SearchSettings
    bars: dict[bool, RefitBar]
    settings: IdentifySettings
    timings: dict[str, float]
    say: Say


def refit_bars(prep: Prepared, chosen: list[CandidateResult], baseline: BaselineFit,
               settings: IdentifySettings) -> dict[bool, RefitBar]:
    """The bar, the baseline's errors and floors on the data each refit searches, by
    "slower than the search window": for step records the fit data (``False``); for
    records through the electronics the search window, or the whole fit window for an
    effect slower than the search window (coil heating: its time constant is 1 s or more,
    the search window 0.4 s; there its cost only rises with the heating, on the fit
    window the true amount lowers it)."""
    if prep.search is prep.fit:
        on_window = {False: (prep.fit, baseline.convergence.final_cost_a)}
        needed = {False}
    else:
        on_window = {False: (prep.search, float(unit_objective(prep.space, prep.search)(
                         baseline.u[None, :])[0])),
                     True: (prep.fit, baseline.convergence.final_cost_a)}
        needed = {slow_effect(c.effect, settings.operation_search_window_s) for c in chosen}
    return {k: RefitBar(d.serial(), c, d.errors(baseline.params).mae_per_file,
                        resolution_floors(d))
            for k, (d, c) in on_window.items() if k in needed}


def _fit_criterion(bar: RefitBar, c: CandidateResult) -> Callable[[ValveParameters], float]:
    """The fit criterion's dBIC of a refit of ``c`` on the data ``bar`` searches, with the
    refit's own effective sample counts (as :func:`~.diagnosis.select` counts them)."""
    def dbic(params: ValveParameters) -> float:
        data = place(bar.data, params)   # the candidate on its own main PWM grids
        return delta_bic(bar.base_mae, data.errors(params).mae_per_file,
                         effective_counts(data, params), len(c.fields), bar.floors)
    return dbic


def polish_candidate(ext: ParameterSpace, data: FitData, params: ValveParameters,
                     baseline: ValveParameters, settings: IdentifySettings,
                     baseline_cost: float | None = None
                     ) -> tuple[ValveParameters, float, str]:
    """Local search of a refitted candidate on the whole fit window: from its search-window
    optimum and from the baseline with the candidate's effect amount; on the main PWM grids
    placed at the former (:mod:`.phase`).

    The baseline (the effect off) is a point of the candidate's model: when neither start
    leads below ``baseline_cost`` (the baseline's cost on ``data`` [A]) and the effect's off
    value lies within its search bounds, the baseline is the refit, and the third element
    says so (else empty): an amount that the search window asked for and the whole fit
    window refuses is not reported as the effect's best.
    """
    fun = unit_objective(ext, place(data, params))
    u_a = ext.to_unit(params)
    own = [b for b in ext.bounds if b.name not in baseline_space(baseline).names]
    mixed = baseline.replace(**{b.name: getattr(params, b.name) for b in own})
    u_b = ext.to_unit(mixed)
    st = SearchSettings(global_samples=0, starts=2,
                        max_iterations=settings.refit_polish_iterations, initial_step=0.03,
                        restarts=1, stall_iterations=30, tolerance=1e-5)
    res = direct_search(fun, np.vstack([u_a, u_b]), st, label='refit polish')
    c_a = float(fun(u_a[None, :])[0])
    best, cost = (params, c_a) if c_a <= res.cost else (ext.params(res.u), float(res.cost))
    inside = all(b.low <= getattr(baseline, b.name) <= b.high for b in own)
    if baseline_cost is not None and cost > baseline_cost and inside:
        return baseline, float(baseline_cost), (
            f'; no point there below the baseline\'s {baseline_cost:.4g} A '
            f'(best {cost:.4g} A): the baseline, the effect off, is the refit')
    return best, cost, ''


@dataclass
class WindowRefit:
    """A refit on a window, judged there and polished on the fit window if it could pay."""

    params: ValveParameters
    cost: float
    how: str
    widened: tuple[str, ...] = ()


def _refit_on_window(c: CandidateResult, job: RefitJob) -> WindowRefit:
    """Refit ``c`` on its window (records through the electronics): stop after the coarse
    profile if nothing beats the bar or the fit criterion shows it cannot pay; else judge
    it there by the fit criterion and polish on the whole fit window only one that could
    pay."""
    span = job.settings.operation_search_window_s
    slow = slow_effect(c.effect, span)
    bar = job.bars[slow]
    window = 'fit window' if slow else 'search window'
    how = (f' (slower than the {span:g} s search window: searched on the fit window)'
           if slow else '')
    fit = job.prep.fit
    criterion = _fit_criterion(bar, c)
    r: RefitResult = refit_effect(job.prep.space, bar.data, job.baseline.params, c.effect,
                                  job.effort, bar_cost=bar.cost, rank_data=fit.serial(),
                                  screen=criterion)
    if r.stopped:
        how += (f' (stopped after the coarse profile: no trial amount brought the '
                f'{window} cost below the baseline\'s {bar.cost:.4g} A)')
    elif r.screened_out:
        how += _screened(r, window)
    dbic_s = criterion(r.params)
    if not r.stopped and dbic_s < DBIC_THRESHOLD:
        p_aug, cost, fell = polish_candidate(r.space, fit.serial(), r.params,
                                             job.baseline.params, job.settings,
                                             job.baseline.convergence.final_cost_a)
        return WindowRefit(p_aug, cost, how + f' ({window} dBIC {dbic_s:.1f}: polished on '
                           f'the fit window{fell})', r.widened)
    cost = float(place(fit.serial(), r.params).cost(r.params.to_vector()[None, :])[0])
    if not r.stopped and not r.screened_out:
        how += (f' ({window} dBIC {dbic_s:.1f}, not below {DBIC_THRESHOLD:g}: cannot pay, '
                'not polished on the fit window, evaluated as found)')
    return WindowRefit(r.params, cost, how, r.widened)


def _refit_coarse(c: CandidateResult, job: RefitJob) -> WindowRefit:
    """Refit ``c`` on the coarse data (fast step records compared at
    :data:`~.problem.SEARCH_RATE_HZ`): the screen after the coarse profile judges on the
    fit data, and a refit that passes it is polished there (every sample)."""
    bar = job.bars[False]
    r: RefitResult = refit_effect(job.prep.space, job.prep.coarse.serial(),
                                  job.baseline.params, c.effect, job.effort,
                                  screen=_fit_criterion(bar, c))
    if r.screened_out:
        cost = sum(place(bar.data, r.params).errors(r.params).mae_per_file.values())
        return WindowRefit(r.params, cost, _screened(r, 'fit'))
    p_aug, cost, fell = polish_candidate(r.space, bar.data, r.params, job.baseline.params,
                                         job.settings, bar.cost)
    return WindowRefit(p_aug, cost, f' (profiles at {SEARCH_RATE_HZ / 1e3:g} kHz, polished '
                       f'on every sample{fell})', r.widened)


def _screened(r: RefitResult, where: str) -> str:
    return (f' (stopped after the coarse profile: {where} dBIC {r.screen_dbic:.1f}, not '
            f'below {SCREEN_DBIC:g}: cannot pay)')


def refit_candidate(c: CandidateResult, job: RefitJob) -> CandidateResult:
    """Refit one candidate (in its own thread, its simulations on that thread without the
    GIL) and record the result on ``c``."""
    t1 = time.perf_counter()
    if job.prep.coarse is not job.prep.search:
        done = _refit_coarse(c, job)
    elif job.prep.search is job.prep.fit:
        bar = job.bars[False]
        # through the electronics the effect's amount is scanned first (rank_data): a
        # leakage inductance through the chopper is sharp in its amount
        r = refit_effect(job.prep.space, bar.data, job.baseline.params, c.effect,
                         job.effort, progress=None, screen=_fit_criterion(bar, c),
                         rank_data=bar.data if job.prep.through_electronics else None)
        done = WindowRefit(r.params, r.cost, _screened(r, 'fit') if r.screened_out else '',
                           r.widened)
    else:
        done = _refit_on_window(c, job)
    c.refitted = True
    c.params = done.params
    c.parameters = {f: getattr(done.params, f) for f in c.fields}
    c.fit_cost = done.cost
    c.bound_widened = list(done.widened)
    dt = time.perf_counter() - t1
    job.timings[f'refit_{c.effect}'] = dt
    job.say(f'refit {c.effect}: cost {done.cost:.6g} A (baseline '
            f'{job.baseline.convergence.final_cost_a:.6g} A), '
            + ', '.join(f'{k} = {v:.4g}' for k, v in c.parameters.items())
            + f'{done.how}; {dt:.1f} s' + ''.join(f' ({w})' for w in done.widened))
    return c


def augmented_stage(prep: Prepared, diag: Diagnosis) -> EvaluatedStage:
    """The augmented model's errors, residuals and intervals (its effects' fields with
    the baseline's); the structure it leaves is added to ``diag``."""
    fit = place(prep.fit, diag.params)   # on its own main PWM grids (:mod:`.phase`)
    val = place(prep.validation, diag.params) if prep.validation is not None else None
    ev = evaluate_stage(diag.params, fit, val)
    aug_space = prep.space
    for eff in diag.kept_effects:
        aug_space = effect_space(aug_space, eff, at=diag.params)
    ev.stage.sensitivity = analyse_sensitivity(
        aug_space, fit, diag.params,
        at_bound=[n for n in fit.at_bound(aug_space, diag.params)
                  if n in prep.space.names],
        nrmse_pct=ev.stage.fit.nrmse_pct)
    describe_remaining(diag, ev.stage)
    return ev


@dataclass
class DiagnosisOutcome:
    """The effect decided on and the model that carries it (:func:`diagnose`)."""

    diagnosis: Diagnosis
    augmented: EvaluatedStage


def _refit_all(prep: Prepared, analysis: BaselineAnalysis, baseline: BaselineFit,
               candidates: list[CandidateResult], settings: IdentifySettings,
               timings: dict[str, float], say: Say) -> None:
    """Refit the chosen candidates, one thread each; the others get their reason."""
    chosen, skipped = choose_refits(candidates, settings)
    for c, why in skipped:
        c.reason = why
        say(f'refit {c.effect} skipped: {why}')
    job = RefitJob(prep, baseline, settings.refit_effort(prep.operational),
                   refit_bars(prep, chosen, baseline, settings), settings, timings, say)
    t0 = time.perf_counter()
    workers = max(1, min(len(chosen), settings.workers))
    if workers == 1:
        for c in chosen:
            refit_candidate(c, job)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(partial(refit_candidate, job=job), chosen))
    timings['refits'] = _lap(say, f'{len(chosen)} refits', t0)


def diagnose(prep: Prepared, baseline: BaselineFit, analysis: BaselineAnalysis,
             settings: IdentifySettings, timings: dict[str, float], say: Say,
             chosen_form: bool = False) -> DiagnosisOutcome:
    """Close the loop: signatures, refits, selection, a second effect, the augmented model,
    and for structure no listed effect explains an open-ended sparse term.
    ``chosen_form``: the records run through a drive electronics' form the data chose (an
    effect then needs structure of the noise's size:
    :func:`.diagnosis.withdraw_below_form_error`)."""
    t_diag = t0 = time.perf_counter()
    candidates = rank_candidates(prep, analysis, settings, say)
    timings['signatures'] = _lap(say, 'signatures', t0)
    _refit_all(prep, analysis, baseline, candidates, settings, timings, say)
    t0 = time.perf_counter()
    diag = select(candidates, prep.fit, prep.validation, baseline.params,
                  baseline_at_bound=analysis.misfit, space=prep.space,
                  determined=analysis.determined)
    timings['selection'] = _lap(say, 'selection', t0)
    diag.evidence += [f'{c.effect}: {w}' for c in candidates
                      if c.effect == diag.effect for w in c.bound_widened]
    if chosen_form and withdraw_below_form_error(diag, baseline.params):
        say(diag.evidence[0])
    if diag.effect != 'none':
        t0 = time.perf_counter()
        second_effect(diag, prep.space, prep.fit, prep.validation,
                      settings.refit_effort(prep.operational), say)
        timings['second_effect'] = _lap(say, 'second effect', t0)
    timings['diagnosis'] = time.perf_counter() - t_diag
    say(f'diagnosis: {diag.effect} (confidence {diag.confidence})')
    for line in diag.evidence:
        say('  ' + line)
    augmented = analysis.evaluated
    if diag.effect != 'none':
        t0 = time.perf_counter()
        augmented = augmented_stage(prep, diag)
        timings['augmented_analysis'] = time.perf_counter() - t0
    if diag.effect == 'none' and diag.unexplained_structure:
        from .unlisted import offer_unlisted
        t0 = time.perf_counter()
        offer_unlisted(diag, prep.fit, prep.validation, baseline.params, say)
        timings['unlisted'] = _lap(say, 'unlisted term', t0)
    describe_misfit(diag, baseline.params)
    if diag.misfit:
        say(diag.misfit['statement'])
    return DiagnosisOutcome(diag, augmented)


# --- after the valve: the electronics for the simulator ----------------------------------

def electronics_after_valve(route: Route, prep: Prepared, params: ValveParameters,
                            settings: IdentifySettings, say: Say) -> DriveReport | None:
    """The drive electronics of records fitted around them (the mean-voltage route),
    identified with the valve held at ``params`` on the same fit span, for the simulator
    and the map; their notes say how well they reproduce the measured mean coil voltage.
    None when no fit record runs through the electronics."""
    records = through_drive_counterparts(route, prep.fit.full)
    if not records:
        return None
    records = refine_phases(records, params, say)
    drive = fit_drive(_fit_data(records, settings), params,
                      effort=settings.final_drive_effort)
    drive.notes.insert(0, 'identified after the valve (fitted around the electronics '
                       'through the measured mean coil voltage), the valve held, for the '
                       'simulator and the map')
    check = check_mean_voltage(records, params, drive.electronics)
    if check is not None:
        drive.notes.append(check.statement())
    say('drive electronics (valve held): ' + ', '.join(
        f'{k} = {v:.4g}' for k, v in drive.values.items())
        + ('; ' + check.statement() if check is not None else ''))
    return drive


# --- the whole loop ----------------------------------------------------------------------

def identify(fit: Sequence[Record], validate: Sequence[Record] = (),
             settings: IdentifySettings = IdentifySettings(), *,
             base: ValveParameters | None = None,
             progress: Callable[[str], None] | None = None) -> Identification:
    """Identify the valve parameters and close the loop.

    Parameters
    ----------
    fit : sequence of Measurement or path
        Records the parameters are fitted on (each needs its supply pressure); paths of
        CSV files or bag directories are read (:func:`.measurements.read_measurements`
        with ``settings.topic`` and ``settings.valve``).
    validate : sequence of Measurement or path
        Hold-out records for validation and for the effect selection.
    settings : IdentifySettings
        What and with which effort.
    base : ValveParameters, optional
        Known parameters (Table 1, orifice); the identified fields are overwritten.
        Default: ``settings.params_file``, else the packaged parameter set.
    progress : callable, optional
        Receives progress lines.

    Returns
    -------
    Identification

    Raises
    ------
    MeasurementFormatError
        A record cannot be read or lacks its supply pressure.
    ParameterError
        The parameter file is refused.
    IdentificationError
        The records leave nothing to compare.
    """
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    inputs, route = route_inputs(read_inputs(fit, validate, settings, base, say), settings,
                                 say)
    run = identify_on_route(inputs, route, settings, say)
    misfit = electronics_misfit(run, settings)
    if misfit is not None:
        t_paper = time.perf_counter() - t_start
        run = choose_after_misfit(inputs, route, settings, run, misfit, say)
        run.result.timings_s['paper_form_run'] = t_paper
    run.result.timings_s['total'] = time.perf_counter() - t_start
    say('time split: ' + ', '.join(f'{k} {v:.1f} s' for k, v in run.result.timings_s.items()))
    return run.result


@dataclass
class RouteRun:
    """One identification on a settled route (:func:`identify_on_route`).

    Attributes
    ----------
    result : Identification
        What the report needs.
    prep : Prepared
        The data it ran on.
    paper_search : SearchResult or None
        The baseline search through the paper's driver (nominal constants), for a later
        choice of the form to reuse.
    """

    result: Identification
    prep: Prepared
    paper_search: SearchResult | None = None


def identify_on_route(inputs: Inputs, route: Route, settings: IdentifySettings, say: Say,
                      paper_search: SearchResult | None = None) -> RouteRun:
    """Stages 2-7 on ``route``: the baseline (through the electronics' form settled by
    ``settings``), its analysis, the diagnosis, the electronics after the valve.
    ``paper_search``: an earlier baseline search through the paper's driver on the same
    data, which a choice of the form compares with instead of searching again."""
    timings: dict[str, float] = {}
    start = search_route(inputs, route, settings, timings, say, paper_search)
    route, prep, rounds = start.route, start.prep, start.rounds
    prep.notes.insert(0, route.note)
    t0 = time.perf_counter()
    baseline = polish_baseline(prep, rounds, settings, say)
    timings['baseline_polish'] = _lap(say, 'baseline polish', t0)
    timings['baseline_fit'] = sum(timings.get(k, 0.0) for k in (
        'baseline_search', 'route_screen', 'electronics', 'baseline_polish'))
    t0 = time.perf_counter()
    analysis = analyse_baseline(prep, baseline, say)
    timings['baseline_analysis'] = _lap(say, 'baseline analysis', t0)
    outcome = None
    if settings.diagnose:
        family = start.elec.family if start.elec else None
        outcome = diagnose(prep, baseline, analysis, settings, timings, say,
                           chosen_form=family is not None and not family.chosen.prior)
    augmented = outcome.augmented if outcome else analysis.evaluated
    drive = analysis.drive
    if route.name == ROUTE_MEAN_VOLTAGE:
        t0 = time.perf_counter()
        after = electronics_after_valve(route, prep, augmented.stage.params, settings, say)
        if after is not None:
            drive = after
            timings['electronics'] = _lap(say, 'drive electronics (valve held)', t0)
    fit_d, val_d, search, coarse = prep.fit, prep.validation, prep.search, prep.coarse
    result = Identification(
        fit_files=fit_d.measurements, val_files=val_d.measurements if val_d else [],
        baseline=analysis.stage, augmented=augmented.stage,
        diagnosis=outcome.diagnosis if outcome else None, start=prep.start,
        space=prep.space, timings_s=timings,
        simulations=fit_d.simulations + (val_d.simulations if val_d else 0)
        + (search.simulations if search is not fit_d else 0)
        + (coarse.simulations if coarse is not search else 0),
        sim_fit={'baseline': analysis.evaluated.current_fit,
                 'augmented': augmented.current_fit},
        sim_val={'baseline': analysis.evaluated.current_val,
                 'augmented': augmented.current_val},
        convergence=baseline.convergence, drive=drive, at_bound=analysis.at_bound,
        notes=prep.notes + analysis.notes, route=route.name, route_screen=start.screen,
        family=start.elec.family if start.elec else None,
        electronics_source=start.elec.source if start.elec else '')
    return RouteRun(result, prep, start.paper_search)


# --- the paper's form misfits: the data choose the form ----------------------------------

#: ... and at least this fraction of the judged current's range: on a record with little or
#: no noise a misfit of a few mA is many times the noise, but the paper's form fits the
#: generator's default circuit to 0.5 % of the range there, while forms it cannot describe
#: leave 3-16 %; a choice costs several runs through the paper's form.
CHOICE_MIN_RANGE_FRACTION = 0.01


def _judged_data(prep: Prepared) -> FitData:
    """The data a run's final model is judged on: the hold-out data, else the fit window."""
    return prep.validation or prep.fit


def _judged_misfit(run: RouteRun) -> StructuredMisfit:
    """The final model's (augmented, else baseline) residual beyond the noise on the
    hold-out data, else on the fit window."""
    data = _judged_data(run.prep)
    params = run.result.augmented.params
    return structured_misfit(data, params, noise_per_file(data, params))


def electronics_misfit(run: RouteRun, settings: IdentifySettings) -> StructuredMisfit | None:
    """The misfit that lets the data choose the electronics' form after a run through the
    paper's driver (:attr:`IdentifySettings.choose_electronics` None), or None: records
    fitted through the electronics, no form given or chosen, and the final model (with
    the effects the diagnosis named) still misses the judged data by at least
    :data:`~.diagnosis.MISFIT_OVER_NOISE` times the noise and
    :data:`CHOICE_MIN_RANGE_FRACTION` of the current's range. A valve effect the diagnosis
    names and explains leaves no such misfit, so it never calls for another form."""
    if (settings.choose_electronics is not None or settings.electronics is not None
            or not run.prep.through_electronics or run.result.family is not None):
        return None
    misfit = _judged_misfit(run)
    data = _judged_data(run.prep)
    span = max((float(np.nanmax(m.current_a) - np.nanmin(m.current_a))
                for m in data.measurements), default=0.0)
    if not misfit.beyond_noise or misfit.structured_a < CHOICE_MIN_RANGE_FRACTION * span:
        return None
    return misfit


def choose_after_misfit(inputs: Inputs, route: Route, settings: IdentifySettings,
                        first: RouteRun, misfit: StructuredMisfit, say: Say) -> RouteRun:
    """The identification again with the form chosen by the data
    (:mod:`.electronics_family`, reusing ``first``'s baseline search through the paper's
    driver); the run whose final model misses the judged data less goes on, and its notes
    say why the form was chosen and what the other run gave."""
    on = 'hold-out' if first.prep.validation is not None else 'fit'
    why = (f'through the paper\'s driver\'s form the model misses the {on} data by '
           f'{1e3 * misfit.structured_a:.3g} mA RMS of structure ({misfit.over_noise:.0f} x '
           f'the noise of {1e3 * misfit.noise_a:.2g} mA, from {misfit.noise_from})')
    say(f'drive electronics: {why}: the data choose the form')
    _LOG.info('drive electronics: %s: the data choose the form', why)
    t0 = time.perf_counter()
    chosen = identify_on_route(inputs, route, replace(settings, choose_electronics=True),
                               say, first.paper_search)
    again = _judged_misfit(chosen)
    family = chosen.result.family
    kept_prior = family is not None and family.chosen.prior
    form = ('they kept the paper\'s driver\'s form' if kept_prior or family is None else
            f'they chose {describe_form(family.chosen.electronics)}')
    if again.structured_a < misfit.structured_a:
        # the choice's searches (through each release, and the paper's form again from
        # the valve they found) can reach a better valve even when the form stays
        note = (f'{why}; the data were let choose the form (--choose-electronics auto): '
                f'{form}, and through it the model misses them by '
                f'{1e3 * again.structured_a:.3g} mA RMS of structure: that run goes on')
        if first.result.diagnosis is not None:
            note += (f'; through the paper\'s driver\'s form at first the answer was '
                     f'{first.result.diagnosis.effect}')
        run = chosen
    else:
        note = (f'{why}; the data were let choose the form (--choose-electronics auto): '
                f'{form}, through which the model misses them by '
                f'{1e3 * again.structured_a:.3g} mA RMS of structure, no less; the run '
                'through the paper\'s driver\'s form is kept')
        run = first
        if kept_prior:
            run.result.family = family
    say('drive electronics: ' + note)
    run.result.notes.insert(0, note)
    run.result.electronics_trigger = {
        'statement': note, 'noise_a': misfit.noise_a, 'noise_from': misfit.noise_from,
        'judged_on': on, 'paper_structured_a': misfit.structured_a,
        'paper_over_noise': misfit.over_noise,
        'paper_answer': first.result.diagnosis.effect if first.result.diagnosis else None,
        'chosen_form': describe_form(family.chosen.electronics) if family else None,
        'chosen_structured_a': again.structured_a,
        'went_on': 'choice' if run is chosen else 'first'}
    run.result.simulations = first.result.simulations + chosen.result.simulations
    run.result.timings_s['electronics_choice_run'] = time.perf_counter() - t0
    return run
