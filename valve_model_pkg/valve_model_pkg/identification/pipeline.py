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


import math

import numpy as np

from ..model.parameters import EFFECTS, ValveParameters
from .diagnosis import (
    CandidateResult, Diagnosis, describe_remaining, refit_effect, score_signatures,
    second_effect, select,
)
from .drive import DriveReport, fit_drive
from .measurements import Measurement, hold_out
from .problem import (
    ErrorFigures, FitData, ParameterSpace, baseline_space, start_point, unit_objective,
)
from .residuals import ResidualReport, analyse_residuals
from .search import SearchSettings, direct_search
from .sensitivity import SensitivityReport, analyse_sensitivity, noise_std

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
    #: Records through the electronics are fitted on at most this much of their length
    #: after their discarded start [s] (the simulation of a chopped record costs about
    #: 25 ms per simulated second; a second holds 20-100 PWM periods).
    operation_fit_window_s: float = 1.0
    #: ... and validated on at most this much [s].
    operation_validation_window_s: float = 3.0
    #: Share of a single record through the electronics held out for validation when no
    #: validation file is given (the last part).
    hold_out_fraction: float = 0.3

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


def _window(m: Measurement, span_s: float) -> Measurement:
    """``m`` cut to ``span_s`` after the start of its compared part (a long record)."""
    from dataclasses import replace
    end = max(m.exclude_before_s, float(m.t_s[0])) + span_s
    if m.t_s[-1] <= end:
        return m
    keep = m.t_s <= end
    return replace(m, t_s=m.t_s[keep], voltage_v=m.voltage_v[keep],
                   current_a=m.current_a[keep],
                   position_m=None if m.position_m is None else m.position_m[keep],
                   n_missing_values=int(np.count_nonzero(~np.isfinite(m.current_a[keep]))),
                   notes=m.notes + (f'compared up to {end:.3g} s of {m.t_s[-1]:.3g} s (the '
                                    f'first {span_s:g} s of its compared part)',))


def prepare_files(fit_files: Sequence[Measurement], val_files: Sequence[Measurement],
                  settings: 'IdentifySettings') -> tuple[list[Measurement], list[Measurement],
                                                         list[str]]:
    """Hold-out of a single operational record, windows of long ones; notes in words."""
    fit, val = list(fit_files), list(val_files)
    notes = []
    if len(fit) == 1 and not val and fit[0].drive is not None:
        f, v = hold_out(fit[0], settings.hold_out_fraction)
        fit, val = [f], [v]
        notes.append(f'one record and no validation file: the last '
                     f'{100 * settings.hold_out_fraction:.0f} % of {fit[0].name} (from '
                     f'{v.held_out_from_s:.3g} s) is held out for validation')
    fit = [_window(m, settings.operation_fit_window_s) if m.drive is not None else m
           for m in fit]
    val = [_window(m, settings.operation_validation_window_s) if m.drive is not None else m
           for m in val]
    return fit, val, notes


def refine_phases(files: list[Measurement], params: ValveParameters,
                  say: Callable[[str], None], electronics=None) -> list[Measurement]:
    """Place each record's main PWM period grid where the current says, within the range
    its command changes allow (1 kHz telemetry bounds a period start to 1 ms): eleven
    trial shifts, the one whose simulated current is closest to the measured one, then
    eleven more around it."""
    from dataclasses import replace
    out = []
    for m in files:
        d = m.drive
        lo, hi = d.phase_range_s if d is not None else (0.0, 0.0)
        if d is None or hi - lo <= 1e-6:
            out.append(m)
            continue
        best, best_cost = 0.0, math.inf
        for width in (hi - lo, (hi - lo) / 10.0):
            centre = best if math.isfinite(best_cost) else 0.5 * (lo + hi)
            for delta in np.linspace(max(lo, centre - width / 2), min(hi, centre + width / 2),
                                     11):
                trial = _window(replace(m, drive=d.shifted(float(delta))), 0.4)
                data = FitData([trial])
                if electronics is not None:
                    data.electronics = electronics
                c = float(data.cost(params.to_vector()[None, :])[0])
                if c < best_cost:
                    best, best_cost = float(delta), c
        new = d.shifted(best)
        say(f'{m.name}: main PWM period grid placed {1e3 * best:+.3f} ms from the middle of '
            f'the range its command changes allow ({1e3 * lo:+.3f}..{1e3 * hi:+.3f} ms)')
        out.append(replace(m, drive=new, voltage_v=new.main_pwm_level(m.t_s),
                           notes=m.notes + (f'main PWM phase refined from the current: first '
                                            f'period start {1e3 * new.period_starts_s[0]:.3f} '
                                            'ms',)))
    return out


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


#: A parameter at a search bound whose 95 % interval is below this [%] is a misfit sign.
MISFIT_CI95_PCT = 50.0
#: The baseline counts as converged when a local polish (fresh simplices around the best
#: point) lowers the cost by less than this fraction of the noise's mean absolute error.
CONVERGENCE_FRACTION = 0.02
#: ... or by less than this relative amount (noise-free data).
CONVERGENCE_RELATIVE = 1e-3


def polish(space: ParameterSpace, data: FitData, u: np.ndarray, cost: float,
           noise_a: float, say: Callable[[str], None], rounds: int = 3,
           others: np.ndarray | None = None) -> tuple[np.ndarray, Convergence]:
    """Polish the baseline until a fresh local search no longer pays (see Convergence).

    The first round also runs independent simplices from ``others`` (other start points:
    the measured values, the global stage's other good points), in lock step: a lower cost
    reached from elsewhere means the search had stopped in a local minimum.
    """
    fun = unit_objective(space, data)
    noise_mae = noise_a * math.sqrt(2.0 / math.pi) if math.isfinite(noise_a) else 0.0
    tol = max(CONVERGENCE_FRACTION * noise_mae, CONVERGENCE_RELATIVE * cost)
    costs = []
    best_u, best_c = u.copy(), cost
    converged = False
    gain = math.inf
    for r in range(rounds):
        starts = best_u[None, :]
        if r == 0 and others is not None and len(others):
            starts = np.vstack([best_u[None, :], np.atleast_2d(others)])
        st = SearchSettings(global_samples=0, starts=starts.shape[0], max_iterations=300,
                            initial_step=0.1 / (r + 1), restarts=2, stall_iterations=60,
                            tolerance=1e-6, seed=r + 1)
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
    statement = (f'baseline converged: local polishes from the optimum and from '
                 f'{0 if others is None else len(others)} other start points lowered the cost '
                 f'(mean absolute error) from {cost:.4g} A to {best_c:.4g} A; the last polish '
                 f'gained {max(gain, 0.0):.2g} A, within '
                 f'{tol:.2g} A = max({100 * CONVERGENCE_FRACTION:g} % of the noise MAE '
                 f'{noise_mae:.3g} A, {CONVERGENCE_RELATIVE:g} of the cost)'
                 if converged else
                 f'baseline NOT shown converged: {rounds} polishes still lowered the cost '
                 f'({cost:.4g} -> {best_c:.4g} A, tolerance {tol:.2g} A)')
    return best_u, Convergence(search_cost_a=cost, polish_costs_a=costs, final_cost_a=best_c,
                               noise_mae_a=noise_mae, tolerance_a=tol, converged=converged,
                               statement=statement)


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


def _stage(params: ValveParameters, fit: FitData, val: FitData | None) -> tuple[
        Stage, list, list]:
    sims_fit = fit.simulate(params.to_vector()[None, :])
    res_fit = [np.where(v, m.current_a - c[0], np.nan)
               for m, v, (c, _) in zip(fit.measurements, fit.valid, sims_fit)]
    rep_fit = analyse_residuals(fit.measurements, res_fit, [x[0] for _, x in sims_fit],
                                params.stroke_m)
    sims_val: list = []
    rep_val = None
    val_err = None
    if val is not None:
        sims_val = val.simulate(params.to_vector()[None, :])
        res_val = [np.where(v, m.current_a - c[0], np.nan)
                   for m, v, (c, _) in zip(val.measurements, val.valid, sims_val)]
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
    fit_files = refine_phases(list(fit_files), base, say)
    val_files = refine_phases(list(val_files), base, say)
    fit_list, val_list, notes = prepare_files(fit_files, val_files, settings)
    for n in notes:
        say(n)
    fit = FitData(fit_list)
    val = FitData(val_list) if val_list else None
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
    say(f'baseline: cost {res.cost:.6g} A after {res.evaluations} simulations')
    u_best, c_best = res.u, res.cost
    drive = None
    if fit.through_electronics:
        # Electronics and valve alternately: the drive constants with the valve held, then
        # the valve again under the identified electronics.
        for _ in range(2):
            drive = fit_drive(fit, space.params(u_best))
            fit.electronics = drive.electronics
            if val is not None:
                val.electronics = drive.electronics
            say('drive electronics: ' + ', '.join(f'{k} = {v:.4g}'
                                                  for k, v in drive.values.items()))
            c_best = float(fun(u_best[None, :])[0])
            again = direct_search(fun, u_best, SearchSettings(
                global_samples=0, starts=1, max_iterations=settings.baseline.max_iterations,
                initial_step=0.08, restarts=2), label='baseline (electronics identified)')
            if again.cost < c_best:
                u_best, c_best = again.u, again.cost
    noise0 = float(np.nanmedian([noise_std(r) for r in fit.residuals(space.params(u_best))]))
    others = [space.to_unit(start)]
    if res.starts_u is not None:
        others += [x for x in res.starts_u if np.max(np.abs(x - u_best)) > 0.05][:3]
    u_best, conv = polish(space, fit, u_best, c_best, noise0, say, others=np.array(others))
    say(conv.statement)
    if fit.through_electronics:
        drive = fit_drive(fit, space.params(u_best))
        fit.electronics = drive.electronics
        if val is not None:
            val.electronics = drive.electronics
    baseline_params = space.params(u_best)
    timings = {'baseline_fit': time.perf_counter() - t0}
    at_bound = fit.at_bound(space, baseline_params)
    if at_bound:
        say('baseline parameters at a search bound (misfit): ' + ', '.join(at_bound))
    t0 = time.perf_counter()
    baseline, sim_fit_b, sim_val_b = _stage(baseline_params, fit, val)
    baseline.sensitivity = analyse_sensitivity(space, fit, baseline_params,
                                               at_bound=at_bound,
                                               nrmse_pct=baseline.fit.nrmse_pct)
    if drive is not None:
        drive = fit_drive(fit, baseline_params, effort=0,
                          inflation=baseline.sensitivity.inflation)
    # A bound reached along a direction the data do not see (b on a step: the damping
    # force is ~1 % of the others) is no misfit; one the data care about is.
    ci = baseline.sensitivity.ci95_pct
    misfit = [n for n in at_bound if ci.get(n) is not None and ci[n] < MISFIT_CI95_PCT]
    if at_bound:
        notes.append('at a search bound: ' + ', '.join(at_bound) + (
            '; the data determine ' + ', '.join(misfit) + ' (95 % CI below '
            f'{MISFIT_CI95_PCT:g} %): a sign of misfit' if misfit else
            '; the data hardly see them (wide intervals): not read as misfit'))
    timings['baseline_analysis'] = time.perf_counter() - t0
    diag = None
    augmented = baseline
    sim_fit_a, sim_val_a = sim_fit_b, sim_val_b
    if settings.diagnose:
        t0 = time.perf_counter()
        residuals = [np.where(v, m.current_a - c, np.nan)
                     for m, v, c in zip(fit.measurements, fit.valid, sim_fit_b)]
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
        diag = select(candidates, fit, val, baseline_params, baseline_at_bound=misfit,
                      space=space)
        if diag.effect != 'none':
            second_effect(diag, space, fit, val, settings.refit, say)
        timings['diagnosis'] = time.perf_counter() - t0
        say(f'diagnosis: {diag.effect} (confidence {diag.confidence})')
        for line in diag.evidence:
            say('  ' + line)
        if diag.effect != 'none':
            augmented, sim_fit_a, sim_val_a = _stage(diag.params, fit, val)
            from .problem import effect_space
            aug_space = space
            for eff in diag.kept_effects:
                aug_space = effect_space(aug_space, eff)
            augmented.sensitivity = analyse_sensitivity(
                aug_space, fit, diag.params,
                at_bound=[n for n in fit.at_bound(aug_space, diag.params)
                          if n in space.names],
                nrmse_pct=augmented.fit.nrmse_pct)
            describe_remaining(diag, augmented)
    timings['total'] = time.perf_counter() - t_start
    ident = Identification(
        fit_files=fit.measurements, val_files=val.measurements if val else [],
        baseline=baseline, augmented=augmented, diagnosis=diag, start=start, space=space,
        timings_s=timings,
        simulations=fit.simulations + (val.simulations if val else 0),
        sim_fit={'baseline': sim_fit_b, 'augmented': sim_fit_a},
        sim_val={'baseline': sim_val_b, 'augmented': sim_val_a},
        convergence=conv, drive=drive, at_bound=at_bound, notes=notes)
    return ident
