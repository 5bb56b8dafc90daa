"""Identification through drive electronics of other forms: the before table's rows again.

Run by hand (not part of ``make test`` or ``make bench``). For each form of the test-data
generator (``tests/datagen/electronics.py``) the records of the before table
(``benchmarks/results/ident_electronics_before.md``, script ``ident_electronics_matrix.py``:
the paper's valve, no effect, a 2 s fit and a 1.5 s validation record, 1 kHz interval-mean
current, 3 mA noise, without ``coil_voltage_mean``), identified by::

    valve_identify --fit FIT --validate VALIDATE --quick --no-diagnosis --no-plots --quiet
        (--electronics YAML | --choose-electronics)
                   --out DIR [--electronics FILE]

without ``--electronics`` (the form chosen by the data) and, for the forms listed in
:data:`GIVEN`, with the suite's description of the generator's form. The table gives the
form named, the validation RMSE of the baseline before (read from the before table) and
after, the wall time and the load. The effect diagnosis is off (the before table's
baseline RMSE does not depend on it; it would double the time).

Usage::

    python benchmarks/ident_electronics_family.py --out /tmp/family \\
        --table benchmarks/results/ident_electronics_family.md
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / 'tests'))

from common import provenance_lines  # noqa: E402
from datagen.electronics import FORMS  # noqa: E402
from datagen.operation import write_operation_record  # noqa: E402

FORM_ORDER = ('timer_hysteresis_zener', 'dip_rise_pi_fast_cap_peak',
              'threshold_pwm_freewheel', 'suite_like')
FIT_SEED, VALIDATE_SEED = 11, 12
BEFORE = HERE / 'results' / 'ident_electronics_before.md'
#: The suite's description of a generator form (``--electronics``), where it has one.
GIVEN = {
    'timer_hysteresis_zener': {
        'peak_end': 'timer', 'max_boost_time_s': 0.005, 'hold': 'hysteresis',
        'holding_current_a': 0.55, 'hysteresis_band_a': 0.06,
        'comparator_frequency_hz': 40000.0, 'hold_decay': 'diode', 'diode_drop_v': 0.7,
        'release': 'zener', 'zener_voltage_v': 36.0},
}


def _before() -> dict[str, float]:
    """Baseline validation RMSE [mA] of each form's ``none`` row without the column."""
    out = {}
    for line in BEFORE.read_text(encoding='utf-8').splitlines():
        cells = [c.strip() for c in line.strip('|').split('|')]
        if len(cells) >= 7 and cells[1] == 'none' and cells[2] == 'no':
            try:
                out[cells[0]] = float(cells[6])
            except ValueError:
                continue
    return out


def _records(work: Path, form: str) -> tuple[Path, Path]:
    folder = work / 'records' / form
    fit, val = folder / 'fit.csv', folder / 'validate.csv'
    for stem, seed, duration in (('fit', FIT_SEED, 2.0), ('validate', VALIDATE_SEED, 1.5)):
        if not (folder / f'{stem}.csv').exists():
            write_operation_record(folder, stem, seed=seed, effect='none', noise_a=3e-3,
                                   duration_s=duration, circuit=FORMS[form])
    return fit, val


def _identify(fit: Path, val: Path, out: Path, electronics: Path | None
              ) -> tuple[int, float, str]:
    exe = shutil.which('valve_identify')
    cmd = [exe] if exe else [sys.executable, '-m', 'valve_model_pkg.cli.identify']
    cmd += ['--fit', str(fit), '--validate', str(val), '--quick', '--no-diagnosis',
            '--no-plots', '--quiet', '--out', str(out)]
    cmd += ['--electronics', str(electronics)] if electronics is not None else \
        ['--choose-electronics']
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    return proc.returncode, time.perf_counter() - start, proc.stderr.strip()[-300:]


def _load() -> str:
    try:
        return Path('/proc/loadavg').read_text().split(' ')[0]
    except OSError:
        return 'unknown'


def _row(form: str, how: str, out: Path, code: int, secs: float, err: str,
         before: float | None, load: str) -> str:
    b = '' if before is None else f'{before:.2f}'
    if code != 0:
        return f'| {form} | {how} | failed ({code}): {err[-80:]} | | {b} | | {secs:.0f} | {load} |'
    rep = json.loads((out / 'report.json').read_text(encoding='utf-8'))
    ef = rep.get('electronics_form') or {}
    fam = ef.get('family') or {}
    same = '; '.join(fam.get('cannot_tell_from') or []) or '-'
    after = 1e3 * rep['baseline']['validation']['rmse']
    named = ef.get('form', '-') + ' (' + ef.get('constants', '') + ')'
    return (f'| {form} | {how} | {named} | {same} | {b} | {after:.2f} | {secs:.0f} '
            f'| {load} |')


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--out', required=True, help='work directory (records, reports)')
    parser.add_argument('--table', required=True, help='Markdown table to write')
    parser.add_argument('--form', action='append', choices=sorted(FORMS))
    parser.add_argument('--no-given', action='store_true', help='skip the --electronics runs')
    args = parser.parse_args(argv)
    work = Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    before = _before()
    head = ['# Identification through drive electronics of other forms: after', '',
            *provenance_lines(), '',
            'Records as in ident_electronics_before.md (the paper\'s valve, no effect, 2 s '
            'fit and 1.5 s validation record, 1 kHz interval means, 3 mA noise, no '
            '`coil_voltage_mean`). `valve_identify --quick --no-diagnosis`, the form chosen '
            'by the data ("chosen") or given with `--electronics` ("given"). RMSE: the '
            'baseline\'s on the validation record; "before" from the before table (the '
            'paper\'s form, constants fitted). Load: 1-min load average at the end of the '
            'run (2 cores shared with other sessions: times scale with it).', '',
            '| generator form | electronics | form named (constants) | cannot tell from '
            '| RMSE before mA | RMSE after mA | time s | load |',
            '|---|---|---|---|---|---|---|---|']
    rows: list[str] = []
    for form in args.form or list(FORM_ORDER):
        fit, val = _records(work, form)
        runs: list[tuple[str, Path | None]] = [('chosen', None)]
        if form in GIVEN and not args.no_given:
            path = work / f'{form}.yaml'
            path.write_text('electronics:\n' + ''.join(
                f'  {k}: {v}\n' for k, v in GIVEN[form].items()), encoding='utf-8')
            runs.append(('given', path))
        for how, elec in runs:
            out = work / 'reports' / f'{form}-{how}'
            code, secs, err = _identify(fit, val, out, elec)
            rows.append(_row(form, how, out, code, secs, err, before.get(form), _load()))
            Path(args.table).write_text('\n'.join(head + rows) + '\n', encoding='utf-8')
            print(re.sub(r'\s+', ' ', rows[-1]), file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
