"""The whole loop: baseline fit, residual study, candidate effects, refits, selection.

:func:`identify` is what ``valve_identify`` runs; it returns an :class:`Identification`
that :mod:`.report` writes out.
"""
from __future__ import annotations

import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Sequence


from ..model.parameters import EFFECTS, ValveParameters
from .diagnosis import CandidateResult, Diagnosis, refit_effect, score_signatures, select
from .measurements import Measurement
from .problem import (
    ErrorFigures, FitData, ParameterSpace, baseline_space, start_point, unit_objective,
)
from .residuals import ResidualReport, analyse_residuals
from .search import SearchSettings, direct_search
from .sensitivity import SensitivityReport, analyse_sensitivity

__all__ = ['IdentifySettings', 'Identification', 'identify']

_LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class IdentifySettings:
    """Effort and scope of :func:`identify`.

    Attributes
    ----------
    baseline : SearchSettings
        Search of the eight baseline parameters (global stage + multi-start).
    refit : SearchSettings
        Search of each candidate's refit (local, from the baseline optimum).
    max_refits : int
        How many candidates (ranked by signature score) are refitted.
    diagnose : bool
        False stops after the baseline fit (paper's Section 4 only).
    """

    baseline: SearchSettings = SearchSettings(global_samples=256, starts=6,
                                              max_iterations=400)
    refit: SearchSettings = SearchSettings(global_samples=0, starts=5, max_iterations=500,
                                           initial_step=0.1, restarts=3)
    max_refits: int = len(EFFECTS)
    diagnose: bool = True

    @classmethod
    def quick(cls, diagnose: bool = True) -> 'IdentifySettings':
        """Smaller effort (tests, previews): fewer global samples, starts and iterations."""
        return cls(baseline=SearchSettings(global_samples=128, starts=4, max_iterations=250),
                   refit=SearchSettings(global_samples=0, starts=5, max_iterations=300,
                                        initial_step=0.1, restarts=2),
                   diagnose=diagnose)


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


def _stage(params: ValveParameters, fit: FitData, val: FitData | None) -> tuple[
        Stage, list, list]:
    sims_fit = fit.simulate(params.to_vector()[None, :])
    res_fit = [m.current_a - c[0] for m, (c, _) in zip(fit.measurements, sims_fit)]
    rep_fit = analyse_residuals(fit.measurements, res_fit, [x[0] for _, x in sims_fit],
                                params.stroke_m)
    sims_val: list = []
    rep_val = None
    val_err = None
    if val is not None:
        sims_val = val.simulate(params.to_vector()[None, :])
        res_val = [m.current_a - c[0] for m, (c, _) in zip(val.measurements, sims_val)]
        rep_val = analyse_residuals(val.measurements, res_val, [x[0] for _, x in sims_val],
                                    params.stroke_m)
        val_err = val.errors(params)
    return (Stage(params=params, fit=fit.errors(params), validation=val_err,
                  residual_fit=rep_fit, residual_validation=rep_val),
            [c[0] for c, _ in sims_fit], [c[0] for c, _ in sims_val])


def identify(fit_files: Sequence[Measurement], val_files: Sequence[Measurement] = (),
             base: ValveParameters | None = None,
             settings: IdentifySettings = IdentifySettings(),
             progress: Callable[[str], None] | None = None) -> Identification:
    """Identify the valve parameters and close the loop.

    Parameters
    ----------
    fit_files : sequence of Measurement
        Files the parameters are fitted on (each needs its supply pressure).
    val_files : sequence of Measurement
        Hold-out files for validation and for the effect selection.
    base : ValveParameters, optional
        Known parameters (Table 1, orifice); the identified fields are overwritten.
        Default: the packaged parameter set.
    settings : IdentifySettings
        Effort.
    progress : callable, optional
        Receives progress lines.

    Returns
    -------
    Identification
    """
    say = progress or (lambda s: None)
    t_start = time.perf_counter()
    if base is None:
        from ..model.parameters import load_parameters
        base = load_parameters()
    # Effects a --params file may switch on are switched off for the baseline: the
    # baseline is the paper's model, the loop decides on effects.
    neutral = {}
    for spec in EFFECTS.values():
        neutral.update(spec.neutral)
    base = base.replace(**neutral)
    fit = FitData(list(fit_files))
    val = FitData(list(val_files)) if val_files else None
    for m in fit.measurements:
        say(f'fit file {m.summary()}')
    for m in (val.measurements if val else []):
        say(f'validation file {m.summary()}')
    space = baseline_space(base)
    start = start_point(space)
    fun = unit_objective(space, fit)
    say('baseline: direct search over ' + ', '.join(space.names))
    t0 = time.perf_counter()
    res = direct_search(fun, space.to_unit(start), settings.baseline, progress=say,
                        label='baseline')
    baseline_params = space.params(res.u)
    timings = {'baseline_fit': time.perf_counter() - t0}
    say(f'baseline: cost {res.cost:.6g} A after {res.evaluations} simulations '
        f'({timings["baseline_fit"]:.1f} s)')
    t0 = time.perf_counter()
    baseline, sim_fit_b, sim_val_b = _stage(baseline_params, fit, val)
    baseline.sensitivity = analyse_sensitivity(space, fit, baseline_params)
    timings['baseline_analysis'] = time.perf_counter() - t0
    diag = None
    augmented = baseline
    sim_fit_a, sim_val_a = sim_fit_b, sim_val_b
    if settings.diagnose:
        t0 = time.perf_counter()
        residuals = [m.current_a - c for m, c in zip(fit.measurements, sim_fit_b)]
        scores = score_signatures(space, fit, baseline_params, residuals)
        order = sorted(scores, key=lambda e: -scores[e][0])
        say('signatures: ' + ', '.join(f'{e} {scores[e][0]:+.2f}' for e in order))
        candidates = [CandidateResult(effect=eff, fields=EFFECTS[eff].fields,
                                      signature_correlation=scores[eff][0],
                                      signature_amplitude=scores[eff][1]) for eff in order]

        def run(c: CandidateResult) -> CandidateResult:
            # Each refit in its own thread, its simulations on that thread without the GIL.
            p_aug, cost, _ = refit_effect(space, fit.serial(), baseline_params, c.effect,
                                          settings.refit, progress=None)
            c.refitted = True
            c.params = p_aug
            c.parameters = {f: getattr(p_aug, f) for f in c.fields}
            c.fit_cost = cost
            say(f'refit {c.effect}: cost {cost:.6g} A (baseline {res.cost:.6g} A), '
                + ', '.join(f'{k} = {v:.4g}' for k, v in c.parameters.items()))
            return c

        workers = max(1, min(settings.max_refits, os.cpu_count() or 1))
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(run, candidates[:settings.max_refits]))
        diag = select(candidates, fit, val, baseline_params)
        timings['diagnosis'] = time.perf_counter() - t0
        say(f'diagnosis: {diag.effect} (confidence {diag.confidence})')
        for line in diag.evidence:
            say('  ' + line)
        if diag.effect != 'none':
            augmented, sim_fit_a, sim_val_a = _stage(diag.params, fit, val)
            from .problem import effect_space
            augmented.sensitivity = analyse_sensitivity(
                effect_space(space, diag.effect), fit, diag.params)
    timings['total'] = time.perf_counter() - t_start
    ident = Identification(
        fit_files=fit.measurements, val_files=val.measurements if val else [],
        baseline=baseline, augmented=augmented, diagnosis=diag, start=start, space=space,
        timings_s=timings,
        simulations=fit.simulations + (val.simulations if val else 0),
        sim_fit={'baseline': sim_fit_b, 'augmented': sim_fit_a},
        sim_val={'baseline': sim_val_b, 'augmented': sim_val_a})
    return ident
