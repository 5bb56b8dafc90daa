"""Write the identification's outcome: report.json, report.md with PNG plots, params.yaml.

``report.json`` layout (the contract ``valve_identify`` is checked against)::

    {
      "baseline":  {"parameters": {...}, "fit": {"iae", "rmse", "nrmse_pct", ...},
                    "validation": {...} | null, "residual": {...}, "sensitivity": {...}},
      "augmented": {... the same, for the model with the selected effect (== baseline
                    when the effect is "none")},
      "diagnosis": {"effect": "<name>|unlisted|none", "confidence": "high|medium|low",
                    "evidence": [...], "numbers": {...}, "candidates": [...ranked...],
                    "unexplained_structure": bool,
                    "model_misfit": {"statement", "structured_rms_a", "noise_std_a",
                                     "noise_from", "over_noise", "on", "where",
                                     "where_text", "phase_share_of_misfit"} | null},
      "unlisted":  {"tried", "claimed", "terms", "coefficients", "errors": {
                    "baseline_fit", "baseline_validation", "augmented_fit",
                    "augmented_validation"}, ...} | null,
      "route": {"name": "mean_coil_voltage|drive_electronics|bare_coil",
                "text": "<how the valve was fitted, in words>",
                "chosen_by_data": {"chosen", "rmse_a", "criterion", "compared_on",
                                   "statement"} | null},
      "current_comparison": {"kind": "samples|interval_means|mixed", "interval_s",
                "text"} | null,
      "drive_electronics": {"values", "bounds", "ci95_pct", "form", "electronics",
                    ...} | null,
      "electronics_form": {"form", "constants", "source", "family": {"chosen",
                    "statement", "cannot_tell_from", "screen", "forms"} | null,
                    "trigger": {"statement", "paper_structured_a", "paper_over_noise",
                    "noise_a", "paper_answer", "chosen_form", "chosen_structured_a",
                    "went_on": "choice"|"first", ...} | null, "file"} | null,
      "files": {...}, "timings_s": {...}, "units": {...}
    }

``iae`` is in A s, ``rmse`` in A, ``nrmse_pct`` in % of the measured current's range;
parameters are SI with the names of ``ValveParameters``. ``params.yaml`` is the full
parameter set in the nested form ``load_parameters`` reads, so ``valve_simulate`` and
``valve_map`` use the identified (and augmented) model directly; for records through the
drive electronics ``electronics.yaml`` beside it holds the electronics identified with it
(form and constants), so ``valve_simulate --params params.yaml --electronics
electronics.yaml`` reproduces the fit.

``unlisted`` is the open-ended sparse term of :mod:`.unlisted`, tried when no listed effect
explains a structured residual; when it pays the effect is ``unlisted``. The model cannot
simulate such a term, so it is never written to ``params.yaml`` (which then holds the
baseline) and ``augmented`` stays the baseline; its errors before and after are in
``unlisted.errors``.

``current_comparison`` says how the current of bench ``pwm`` records through the drive
electronics was compared: sample by sample (the samples follow the chopper) or in interval
means (:mod:`.pwm_compare`; the errors are then those of the means); null for other
records.

``model_misfit`` is set when the answer is ``none`` but the baseline misses the record by
a structured error well above the noise that no candidate explains: the model (valve or
drive electronics) does not describe the record. Its statement, with the size of the
misfit and the phase of the drive cycle it sits in, is then the report's first line.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import yaml

from ..model.parameters import EFFECTS, ValveParameters
from .mean_voltage import ROUTE_TEXT
from .pipeline import Identification, Stage
from .problem import IDENTIFIED_FIELDS, PAPER_SYMBOLS, TABLE2_MEASURED, equivalent_gap_m

__all__ = ['write_report', 'report_dict']


def _clean(x: object) -> object:
    """JSON-safe: non-finite floats become null, numpy scalars plain numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _parameters(p: ValveParameters) -> dict[str, float]:
    out = {n: getattr(p, n) for n in IDENTIFIED_FIELDS}
    for spec in EFFECTS.values():
        for f in spec.fields:
            out[f] = getattr(p, f)
    out['equivalent_gap_m'] = equivalent_gap_m(p)
    return out


def _stage_dict(s: Stage) -> dict[str, object]:
    return {
        'parameters': _parameters(s.params),
        'active_effects': list(s.params.active_effects()),
        'fit': s.fit.to_json(),
        'validation': s.validation.to_json() if s.validation else None,
        'iae': s.fit.iae, 'rmse': s.fit.rmse, 'nrmse_pct': s.fit.nrmse_pct,
        'residual': {'fit': s.residual_fit.to_json(),
                     'validation': s.residual_validation.to_json()
                     if s.residual_validation else None},
        'sensitivity': s.sensitivity.to_json() if s.sensitivity else None,
    }


def report_dict(ident: Identification) -> dict[str, object]:
    """The content of report.json."""
    d = ident.diagnosis
    diag = None
    if d is not None:
        diag = {
            'effect': d.effect,
            'confidence': d.confidence,
            'unexplained_structure': d.unexplained_structure,
            'evidence': d.evidence,
            'numbers': d.numbers,
            'residual_dominant_phase': ident.baseline.residual_fit.dominant_phase,
            'candidates': [c.to_json() for c in d.candidates],
            'kept_effects': d.kept_effects,
            'indistinguishable_from': d.indistinguishable,
            'second_effect': d.second,
            'remaining_structure': d.remaining,
            'model_misfit': d.misfit,
        }
    unl = getattr(d, 'unlisted', None) if d is not None else None
    return _clean({
        'baseline': _stage_dict(ident.baseline),
        'augmented': _stage_dict(ident.augmented),
        'diagnosis': diag,
        'unlisted': unl.to_json() if unl is not None else None,
        'route': {'name': ident.route, 'text': ROUTE_TEXT[ident.route],
                  'chosen_by_data': (ident.route_screen.to_json()
                                     if ident.route_screen is not None else None)},
        'current_comparison': _comparison(ident),
        'start_parameters': _parameters(ident.start),
        'table2_measured': TABLE2_MEASURED,
        'search_bounds': {b.name: [b.low, b.high] for b in ident.space.bounds},
        'files': {
            'fit': [{'file': m.source, 'summary': m.summary(), 'notes': list(m.notes)}
                    for m in ident.fit_files],
            'validation': [{'file': m.source, 'summary': m.summary(), 'notes': list(m.notes)}
                           for m in ident.val_files],
        },
        'baseline_convergence': ident.convergence.to_json() if ident.convergence else None,
        'drive_electronics': ident.drive.to_json() if ident.drive else None,
        'electronics_form': _electronics_form(ident),
        'baseline_at_search_bound': ident.at_bound,
        'data_notes': ident.notes,
        'timings_s': ident.timings_s,
        'simulations': ident.simulations,
        'units': {'iae': 'A s', 'rmse': 'A', 'nrmse_pct': '% of measured current range',
                  'parameters': 'SI (names of ValveParameters)'},
    })


def _comparison(ident: Identification) -> dict[str, object] | None:
    """How the current of pwm records through the electronics was compared (sample by
    sample or in interval means, :func:`.pwm_compare.comparison_statement`)."""
    from .pwm_compare import comparison_statement
    st = comparison_statement(list(ident.fit_files) + list(ident.val_files))
    return st.to_json() if st is not None else None


def _electronics_form(ident: Identification) -> dict[str, object] | None:
    """Which drive electronics the records were identified through, and from where."""
    if ident.drive is None:
        return None
    from .electronics_family import describe_constants, describe_form
    cfg = ident.drive.electronics
    return {'form': describe_form(cfg), 'constants': describe_constants(cfg),
            'source': ident.electronics_source,
            'family': ident.family.to_json() if ident.family is not None else None,
            'trigger': ident.electronics_trigger, 'file': 'electronics.yaml'}


def _electronics_section(form: dict | None) -> list[str]:
    """The drive electronics' form, where it came from, the forms compared."""
    if not form:
        return []
    lines = [f'**Drive electronics: {form["form"]}**; constants {form["constants"]} '
             f'({form["source"]}; in electronics.yaml, for `valve_simulate --electronics`).',
             '']
    if form.get('trigger'):
        lines += ['Why the form was chosen: ' + form['trigger']['statement'] + '.', '']
    fam = form.get('family')
    if fam:
        lines += [fam['statement'] + '.', '', '| form | search MAE [mA] | fit RMSE [mA] | '
                  'hold-out RMSE [mA] | dBIC fit | dBIC hold-out |', '|---|---|---|---|---|---|']
        for f in fam['forms']:
            name = f['form'] + (' (prior)' if f.get('prior') else '') + (
                ' (at bound: ' + ', '.join(f['at_search_bound']) + ')'
                if f.get('at_search_bound') else '')
            lines.append(f'| {name} | {_fmt(f["search_cost_a"], 1e3)} | '
                         f'{_fmt(f["fit_rmse_a"], 1e3)} | {_fmt(f["validation_rmse_a"], 1e3)} | '
                         f'{_fmt(f["delta_bic_fit"], 1, 3)} | '
                         f'{_fmt(f["delta_bic_validation"], 1, 3)} |')
        lines.append('')
        for part, opts in fam['screen'].items():
            lines.append(f'- screen of the {part}: ' + ', '.join(
                f'{o["option"]} {_fmt(o["search_cost_a"], 1e3)} mA' for o in opts))
        lines.append('')
    return lines


def _smooth(t: np.ndarray, r: np.ndarray, window_s: float = 0.5e-3) -> np.ndarray:
    """Moving mean over about ``window_s`` (missing samples ignored): shows structure."""
    dt = float(np.median(np.diff(t)))
    window_s = max(window_s, (t[-1] - t[0]) / 200.0)  # long records: 1/200 of the span
    n = max(1, int(round(window_s / dt)))
    ok = np.isfinite(r)
    kern = np.ones(n)
    num = np.convolve(np.where(ok, r, 0.0), kern, mode='same')
    den = np.convolve(ok.astype(float), kern, mode='same')
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(den > 0, num / den, np.nan)


def _plot(ident: Identification, out: Path) -> list[str]:
    """PNG plots: currents and residuals, before and after; returns the file names."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    names = []
    sets = [('fit', ident.fit_files, ident.sim_fit)]
    if ident.val_files:
        sets.append(('validation', ident.val_files, ident.sim_val))
    aug = ident.diagnosis is not None and ident.diagnosis.effect not in ('none', 'unlisted')
    unl = getattr(ident.diagnosis, 'unlisted', None) if ident.diagnosis is not None else None
    unl_cur = unl.currents if unl is not None and unl.claimed else {}
    for role, files, sims in sets:
        for k, m in enumerate(files):
            fig, ax = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
            t_ms = m.t_s * 1e3
            ax[0].plot(t_ms, m.current_a, '.', ms=1.5, color='0.5', label='measured')
            ax[0].plot(t_ms, sims['baseline'][k], '-', lw=1.2, label='baseline model')
            r_b = m.current_a - sims['baseline'][k]
            ax[1].plot(t_ms, r_b * 1e3, '-', lw=0.4, alpha=0.35, color='C0')
            ax[1].plot(t_ms, _smooth(m.t_s, r_b) * 1e3, '-', lw=1.6, color='C0',
                       label='baseline residual (moving mean; thin: raw)')
            if aug:
                lab = f'augmented ({ident.diagnosis.effect})'
                ax[0].plot(t_ms, sims['augmented'][k], '--', lw=1.2, label=lab)
                r_a = m.current_a - sims['augmented'][k]
                ax[1].plot(t_ms, r_a * 1e3, '-', lw=0.4, alpha=0.35, color='C1')
                ax[1].plot(t_ms, _smooth(m.t_s, r_a) * 1e3, '-', lw=1.6, color='C1',
                           label='augmented residual (moving mean)')
            if unl_cur.get(role):
                lab = 'baseline + unlisted term (linearised; not in params.yaml)'
                ax[0].plot(t_ms, unl_cur[role][k], '--', lw=1.2, label=lab)
                r_u = m.current_a - unl_cur[role][k]
                ax[1].plot(t_ms, _smooth(m.t_s, r_u) * 1e3, '-', lw=1.6, color='C2',
                           label='residual with the unlisted term (moving mean)')
            ax[0].set_ylabel('current [A]')
            ax[0].set_title(f'{role}: {m.name}')
            ax[0].legend(loc='lower right')
            ax[1].set_ylabel('measured - simulated [mA]')
            ax[1].set_xlabel('time [ms]')
            ax[1].axhline(0.0, color='k', lw=0.5)
            ax[1].legend(loc='upper right')
            fig.tight_layout()
            name = f'{role}_{k}_{Path(m.name).stem}.png'
            fig.savefig(out / name, dpi=90)
            plt.close(fig)
            names.append(name)
    return names


def _gain(pct: float | None) -> str:
    """An error reduction [%] for the table; a rise beyond tenfold reads as such (against
    a baseline error near zero the percentage means nothing)."""
    if pct is not None and pct < -900.0:
        return 'rises > 10x'
    return _fmt(pct, 1, 3)


def _fmt(v: float | None, scale: float = 1.0, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '-'
    return f'{v * scale:.{digits}g}'


def _unlisted_section(u: dict | None) -> list[str]:
    """report.md lines on the open-ended sparse term (empty when it was not tried)."""
    if not u:
        return []
    lines = ['', '## Effect outside the list: sparse term in the voltage balance', '']
    if not u['tried']:
        return lines + [f'Not tried: {u["reason"]}.']
    lines += [f'Equation searched: `{u["equation"]}`; the terms are evaluated on the '
              'model\'s simulation and the baseline parameters move with them (a joint '
              f'least-squares step, simulated). Rule: {u["rule"]}.', '']
    verdict = ('**Claimed as `unlisted`** (confidence ' + str(u['confidence']) + ')'
               if u['claimed'] else '**Not claimed**: ' + str(u['reason']))
    lines += [verdict + '. No listed effect is named for it.', '']
    if u['terms']:
        lines += ['| term | coefficient | unit |', '|---|---|---|']
        for n in u['terms']:
            lines.append(f'| `{n}` | {_fmt(u["coefficients"][n])} | '
                         f'{u["coefficient_units"][n]} |')
        lines.append('')
    moved = u.get('baseline_parameters_with_term') or {}
    if moved and u['claimed']:
        lines += ['Baseline parameters with the term: ' + ', '.join(
            f'{PAPER_SYMBOLS.get(n, n)} {_fmt(v)}' for n, v in moved.items()
            if n in PAPER_SYMBOLS) + ' (report.json `unlisted`).', '']
    e = u.get('errors') or {}
    if e:
        lines += ['| model | data | IAE [A s] | RMSE [mA] | NRMSE [%] |',
                  '|---|---|---|---|---|']
        for key, label in (('baseline_fit', ('baseline', 'fit')),
                           ('augmented_fit', ('baseline + term', 'fit')),
                           ('baseline_validation', ('baseline', 'validation')),
                           ('augmented_validation', ('baseline + term', 'validation'))):
            f = e.get(key)
            if f:
                lines.append(f'| {label[0]} | {label[1]} | {_fmt(f["iae"])} | '
                             f'{_fmt(f["rmse"], 1e3)} | {_fmt(f["nrmse_pct"], 1, 3)} |')
        lines.append('')
    lines.append('The model (kernel) cannot simulate this term, so its coefficients are not '
                 'in params.yaml (it holds the baseline parameters); they are in report.json '
                 'under `unlisted`.')
    return lines


def _markdown(rep: dict, ident: Identification, plots: list[str]) -> str:
    b, a, d = rep['baseline'], rep['augmented'], rep['diagnosis']
    lines = ['# Valve identification report', '']
    misfit = d.get('model_misfit') if d is not None else None
    if misfit:
        lines[0] += ': the model does not describe this record'
        lines += [f'**Diagnosis: the model (valve or electronics) does not describe this '
                  f'record**: {1e3 * misfit["structured_rms_a"]:.3g} mA RMS of structured '
                  f'misfit ({misfit["over_noise"]:.0f} x the noise), mostly in '
                  f'{misfit["where_text"]}; no listed effect explains it (effect '
                  f'`{d["effect"]}`: none claimed; confidence {d["confidence"]}).', '']
    elif d is not None:
        lines += [f'**Diagnosis: `{d["effect"]}`** (confidence {d["confidence"]}).', '']
    if d is not None:
        lines += [f'- {e}' for e in d['evidence']]
        lines += ['', f'Rule: {d["numbers"]["rule"]}.', '']
    lines += [f'**Valve fitted {rep["route"]["text"]}.**', '']
    if rep['route'].get('chosen_by_data'):
        lines += [f'**Route.** {rep["route"]["chosen_by_data"]["statement"]}.', '']
    if rep.get('current_comparison'):
        lines += [f'**Current comparison.** {rep["current_comparison"]["text"]}.', '']
    conv = rep.get('baseline_convergence')
    if conv:
        lines += [f'**Baseline convergence.** {conv["statement"]}.', '']
    if rep.get('baseline_at_search_bound'):
        lines += ['**Baseline parameters at a search bound (never reported pinned down; '
                  'where the data determine them, a sign of misfit that the diagnosis does '
                  'not read as an effect):** '
                  + ', '.join(rep['baseline_at_search_bound']) + '.', '']
    if d is not None and d.get('remaining_structure'):
        rs = d['remaining_structure']

        def _num(value, scale: float = 1.0) -> str:
            # a figure the residual analysis could not give is said, not formatted
            return 'n/a' if value is None else f'{scale * value:.2f}'
        lines += [f'**Structure left after {" + ".join(d["kept_effects"])}** ({rs["on"]} '
                  f'data): {_num(rs["structured_rms_a"], 1e3)} mA RMS beyond '
                  f'{_num(rs["noise_std_a"], 1e3)} mA noise '
                  f'({_num(rs["structured_over_noise"])} x noise, '
                  f'{"white" if rs["white"] else "not white"}, mostly '
                  f'{rs["dominant_phase"]}).', '']
    if d is not None and d.get('second_effect'):
        se = d['second_effect']
        lines += [f'**Second effect** tried on top: `{se["effect"]}`, dBIC fit '
                  f'{_fmt(se["delta_bic_fit"], 1, 4)}, validation '
                  f'{_fmt(se["delta_bic_validation"], 1, 4)}: '
                  f'{"also paid for its parameters; kept" if se["kept"] else "did not pay"}.',
                  '']
    for n in rep.get('data_notes') or []:
        lines += [f'- {n}']
    if rep.get('data_notes'):
        lines.append('')
    drv = rep.get('drive_electronics')
    if drv:
        lines += ['## Drive electronics (identified within bounds)', '']
        lines += _electronics_section(rep.get('electronics_form'))
        lines += [
                  '| constant | nominal | identified | bounds | 95 % CI | pinned down |',
                  '|---|---|---|---|---|---|']
        for k, v in drv['values'].items():
            ci = drv['ci95_pct'].get(k)
            lo, hi = drv['bounds'][k]
            state = ('at bound (misfit)' if k in drv['at_search_bound'] else
                     'yes' if k in drv['pinned_down'] else
                     'not carried by the data' if not drv['carried_by_the_data'][k] else 'no')
            lines.append(f'| {k} | {_fmt(drv["nominal"][k])} | {_fmt(v)} | {_fmt(lo)}..'
                         f'{_fmt(hi)} | {"-" if ci is None else f"+-{ci:.2g} %"} | {state} |')
        lines += [f'- {n}' for n in drv['notes']] + ['']
    lines += ['## Errors before and after', '',
              '| model | data | IAE [A s] | RMSE [mA] | NRMSE [%] |', '|---|---|---|---|---|']
    for label, s in (('baseline', b), ('augmented', a)):
        for role in ('fit', 'validation'):
            e = s[role]
            if e:
                lines.append(f'| {label} | {role} | {_fmt(e["iae"])} | '
                             f'{_fmt(e["rmse"], 1e3)} | {_fmt(e["nrmse_pct"], 1, 3)} |')
    lines += ['', '## Parameters', '',
              '| parameter | symbol | Table 2 measured | start | baseline | augmented | '
              '95 % CI (baseline) |', '|---|---|---|---|---|---|---|']
    sens = b['sensitivity'] or {}
    ci = sens.get('ci95_pct', {})
    for n in IDENTIFIED_FIELDS:
        meas = TABLE2_MEASURED.get(n)
        c = ci.get(n)
        lines.append(f'| {n} | {PAPER_SYMBOLS[n]} | {_fmt(meas)} | '
                     f'{_fmt(rep["start_parameters"][n])} | {_fmt(b["parameters"][n])} | '
                     f'{_fmt(a["parameters"][n])} | '
                     f'{"not identifiable alone" if c is None else f"+-{c:.2g} %"} |')
    gap = sens.get('derived', {}).get('equivalent_gap')
    if gap:
        lines.append(f'| equivalent gap s = l_c/mu_r + 2 x_t | s | - | - | '
                     f'{_fmt(b["parameters"]["equivalent_gap_m"])} | '
                     f'{_fmt(a["parameters"]["equivalent_gap_m"])} | '
                     f'+-{_fmt(gap["ci95_pct"], 1, 2)} % |')
    # The effect's own fields: their interval from the augmented model's sensitivity (a
    # coil heating's R_th and tau are not pinned down apart on a record shorter than tau).
    sens_a = a.get('sensitivity') or {}
    effect_fields: list[str] = []
    if d is not None and d['effect'] in EFFECTS:
        effect_fields = list(EFFECTS[d['effect']].fields)
        for f in effect_fields:
            c = sens_a.get('ci95_pct', {}).get(f)
            lines.append(f'| {f} | ({d["effect"]}) | - | neutral | neutral | '
                         f'{_fmt(a["parameters"][f])} | '
                         f'{"" if c is None else f"+-{c:.2g} % (augmented)"} |')
    lines += _unlisted_section(rep.get('unlisted'))
    lines += ['', '## What the data pin down', '']
    if sens:
        lines.append(f'Pinned down (95 % CI below 5 %): {", ".join(sens["pinned_down"])}.')
        lines.append(f'Not pinned down by this data: {", ".join(sens["not_pinned_down"])}.')
        for w in sens['weak_directions']:
            std = w['rel_std_pct']
            lines.append(f'- weak direction `{w["combination"]}`: '
                         f'{"invisible to the data" if std is None else f"std {std:.3g} %"}')
        lines += [f'- {n}' for n in sens['notes']]
    for w in sens_a.get('weak_directions', []):
        if any(f in w['components'] for f in effect_fields):
            std = w['rel_std_pct']
            lines.append(f'- augmented model, weak direction `{w["combination"]}`: '
                         f'{"invisible to the data" if std is None else f"std {std:.3g} %"}')
    lines += ['', '## Residual of the baseline model', '']
    for role in ('fit', 'validation'):
        r = b['residual'][role]
        if r:
            lines.append(f'**{role}** (white: {r["white"]}, dominant phase: '
                         f'{r["dominant_phase"]})')
            lines += [f'- {s}' for s in r['summary']]
            lines.append('')
            lines += ['| phase | share of residual energy | RMS / noise (first file) |',
                      '|---|---|---|']
            ph = r['files'][0]['phases']
            for p, share in r['phase_share_of_energy'].items():
                ron = ph.get(p, {}).get('rms_over_noise')
                lines.append(f'| {p} | {100 * share:.1f} % | {_fmt(ron, 1, 3)} |')
            lines.append('')
    if d is not None:
        lines += ['## Candidate effects (ranked by validation gain)', '',
                  '| effect | signature corr. | fit gain [%] | validation gain [%] | '
                  'dBIC fit | dBIC val | structure explained [%] | kept | reason |',
                  '|---|---|---|---|---|---|---|---|---|']
        for c in d['candidates']:
            lines.append(
                f'| {c["effect"]} | {_fmt(c["signature_correlation"], 1, 2)} | '
                f'{_gain(c["fit_error_reduction_pct"])} | '
                f'{_gain(c["validation_error_reduction_pct"])} | '
                f'{_fmt(c["delta_bic_fit"], 1, 4)} | {_fmt(c["delta_bic_validation"], 1, 4)} | '
                f'{_fmt(c["structure_explained_pct"], 1, 3)} | {c["kept"]} | {c["reason"]} |')
    lines += ['', '## Plots', '']
    lines += [f'![{p}]({p})' for p in plots]
    lines += ['', '## Files', '']
    for role in ('fit', 'validation'):
        for f in rep['files'][role]:
            lines.append(f'- {role}: {f["summary"]}')
            lines += [f'  - {n}' for n in f['notes']]
    t = rep['timings_s']
    lines += ['', f'Run time {t.get("total", 0):.1f} s, {rep["simulations"]} simulations.',
              '', 'Time split: ' + ', '.join(f'{k} {v:.1f} s' for k, v in t.items()
                                             if k != 'total') + '.', '']
    return '\n'.join(lines)


def write_report(ident: Identification, out_dir: str | Path, *, plots: bool = True
                 ) -> dict[str, object]:
    """Write report.json, report.md (+ PNGs) and params.yaml into ``out_dir``.

    Returns
    -------
    dict
        The report.json content.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep = report_dict(ident)
    (out / 'report.json').write_text(json.dumps(rep, indent=2), encoding='utf-8')
    names = _plot(ident, out) if plots else []
    (out / 'report.md').write_text(_markdown(rep, ident, names), encoding='utf-8')
    header = ('# Valve parameters identified by valve_identify from:\n'
              + ''.join(f'#   fit: {m.source}\n' for m in ident.fit_files)
              + ''.join(f'#   validation: {m.source}\n' for m in ident.val_files)
              + f'# Diagnosis: {rep["diagnosis"]["effect"] if rep["diagnosis"] else "-"}\n'
              + ('# The unlisted term is not in this file (the model cannot simulate it): '
                 'see report.json "unlisted".\n'
                 if rep['diagnosis'] and rep['diagnosis']['effect'] == 'unlisted' else '')
              + '# Loadable with valve_model_pkg.model.load_parameters (valve_simulate, '
              'valve_map).\n')
    body = yaml.safe_dump(_clean(ident.augmented.params.to_dict()), sort_keys=False)
    (out / 'params.yaml').write_text(header + body, encoding='utf-8')
    if ident.drive is not None:
        text = ident.drive.electronics.to_yaml()
        (out / 'electronics.yaml').write_text(
            '# Drive electronics identified by valve_identify with params.yaml: '
            f'{rep["electronics_form"]["form"]}\n# ({ident.electronics_source}). '
            'Read with --electronics (valve_simulate, valve_map, the emulator).\n' + text,
            encoding='utf-8')
    return rep
