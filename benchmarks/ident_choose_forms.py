"""The drive electronics' form chosen by the data, on the test-data generator's forms.

Run by hand (not part of ``make test`` or ``make bench``). For each form of the generator
(``tests/datagen/electronics.py``; ``generator_default`` is its default circuit) a clean
operational record pair as the tests build it (``datagen.cache.electronics_pair``: the
paper's valve, a 1.5 s fit and a 1.2 s validation record, 1 kHz interval-mean current,
3 mA noise, no ``coil_voltage_mean``) is identified through the library entry with
``quick=True, diagnose=False`` and the form chosen by the data every time (``--choice
always``, the default here), only when the paper's form misfits (``--choice auto``, the
identification's default) or never (``--choice never``, or ``--paper``). The table gives
the baseline's validation RMSE against the noise, the form named, where in the drive
cycle the misfit sits (share of the validation residual's energy above the noise per
phase of ``residuals.drive_phase_masks``), the wall time and the load.

Usage::

    python benchmarks/ident_choose_forms.py --out /tmp/choose \\
        --table benchmarks/results/ident_choose_forms.md [--form F ...]
        [--choice always|auto|never | --paper]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / 'tests'))

from common import provenance_lines  # noqa: E402
from datagen.cache import ELECTRONICS_PAIR_NOISE_A, electronics_pair  # noqa: E402
from datagen.electronics import FORMS  # noqa: E402

from valve_model_pkg.identification import IdentifySettings, identify  # noqa: E402
from valve_model_pkg.identification.electronics_family import (  # noqa: E402
    describe_constants, describe_form,
)
from valve_model_pkg.identification.problem import FitData  # noqa: E402
from valve_model_pkg.identification.residuals import DRIVE_PHASES  # noqa: E402
from valve_model_pkg.identification.residuals import drive_phase_masks  # noqa: E402

NOISE_A = ELECTRONICS_PAIR_NOISE_A
FORM_ORDER = ('generator_default', 'dip_rise_pi_fast_cap_peak', 'timer_hysteresis_zener',
              'threshold_pwm_freewheel', 'dip_pi_slow_cap_unblocked', 'suite_like')


def misfit_shares(ident) -> dict[str, float]:
    """Share of the validation residual's energy above the noise per drive phase."""
    data = FitData(ident.val_files)
    data.electronics = ident.drive.electronics
    excess = {}
    for m, r in zip(ident.val_files, data.residuals(ident.baseline.params)):
        for name, mask in drive_phase_masks(m).items():
            sel = mask & np.isfinite(r)
            excess[name] = excess.get(name, 0.0) + max(
                float(np.sum(r[sel] ** 2)) - sel.sum() * NOISE_A ** 2, 0.0)
    total = sum(excess.values())
    return {k: (v / total if total > 0 else 0.0) for k, v in excess.items()}


#: ``--choice`` and :attr:`IdentifySettings.choose_electronics`.
CHOICES = {'always': True, 'auto': None, 'never': False}


def _electronics(ident, choice: str) -> str:
    """How the form was settled, in a word or two."""
    if choice != 'auto':
        return 'chosen' if choice == 'always' else 'paper'
    trig = ident.electronics_trigger
    if trig is None:
        return 'auto: paper (no misfit)'
    run = 'the choice\'s run' if trig['went_on'] == 'choice' else 'the paper\'s run'
    return f'auto: {run} (paper\'s form {trig["paper_over_noise"]:.0f}x noise)'


def run_form(base: Path, form: str, choice: str) -> dict[str, object]:
    fit, val = electronics_pair(base, form)
    start = time.perf_counter()
    ident = identify([fit], [val], IdentifySettings(quick=True, diagnose=False,
                                                    choose_electronics=CHOICES[choice]))
    secs = time.perf_counter() - start
    cfg = ident.drive.electronics
    return {'form': form, 'electronics': _electronics(ident, choice),
            'named': describe_form(cfg), 'constants': describe_constants(cfg),
            'rmse_a': ident.baseline.validation.rmse, 'time_s': secs,
            'load': os.getloadavg()[0], 'shares': misfit_shares(ident)}


def row(r: dict[str, object]) -> str:
    shares = ', '.join(f'{k} {100 * v:.0f} %' for k, v in r['shares'].items()
                       if v >= 0.05)
    return (f'| {r["form"]} | {r["electronics"]} | {r["named"]} ({r["constants"]}) '
            f'| {1e3 * r["rmse_a"]:.2f} | {r["rmse_a"] / NOISE_A:.2f} | {shares} '
            f'| {r["time_s"]:.0f} | {r["load"]:.1f} |')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--out', required=True, help='work directory (records, json)')
    parser.add_argument('--table', required=True, help='Markdown table to write')
    parser.add_argument('--form', action='append', choices=sorted(FORMS))
    parser.add_argument('--choice', choices=tuple(CHOICES), default='always',
                        help='when the data choose the form (default always)')
    parser.add_argument('--paper', action='store_true', help='the paper\'s form (--choice '
                        'never)')
    args = parser.parse_args(argv)
    work = Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    head = ['# The form chosen by the data on the generator\'s forms', '',
            *provenance_lines(), '',
            'Records of test_identification_electronics.py (the paper\'s valve, no effect, '
            '1.5 s fit and 1.2 s validation record, 1 kHz interval means, 3 mA noise, no '
            '`coil_voltage_mean`); `identify(quick=True, diagnose=False, '
            f'choose_electronics={CHOICES["never" if args.paper else args.choice]})`. RMSE: the '
            'baseline\'s on the validation record. Misfit: share of the validation '
            'residual\'s energy above the noise per drive phase (phases of '
            f'{", ".join(DRIVE_PHASES)}; shares below 5 % left out). Load: 1-min load '
            'average at the end of the run.', '',
            '| generator form | electronics | form named (constants) | RMSE mA '
            '| RMSE / noise | misfit sits in | time s | load |',
            '|---|---|---|---|---|---|---|---|']
    rows: list[str] = []
    results = []
    for form in args.form or list(FORM_ORDER):
        r = run_form(work / 'records', form, 'never' if args.paper else args.choice)
        results.append(r)
        rows.append(row(r))
        Path(args.table).write_text('\n'.join(head + rows) + '\n', encoding='utf-8')
        (work / 'results.json').write_text(json.dumps(results, indent=1), encoding='utf-8')
        print(rows[-1], file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
