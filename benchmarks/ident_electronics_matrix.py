"""Identification through drive electronics of other forms: a matrix of operational records.

Run by hand (not part of ``make test`` or ``make bench``): for each drive-electronics form
of the test-data generator (``tests/datagen/electronics.py``: peak end, hold, release,
reverse blocking, written apart from the suite's) and each effect, two operational records
of the paper's valve with that effect (a fit record and a validation record with other
duty schedules and noise draws; 1 kHz interval-mean current, Gaussian noise), with and
without the ``coil_voltage_mean`` column (the same current, so the pair differs only by the
column), then::

    valve_identify --fit FIT --validate VALIDATE --quick --no-plots --quiet --out DIR

and tabulate: the effect named, its confidence, the baseline and augmented validation NRMSE
and RMSE, the noise the report estimated, the structure it saw, electronics constants at a
search bound, and the wall time. Cells run in priority order until the time budget is used;
the table is rewritten after every cell (a stopped run keeps what it has) and lists the
cells not run.

Usage::

    python benchmarks/ident_electronics_matrix.py --out /tmp/matrix \
        --table benchmarks/results/ident_electronics_before.md --budget-min 90

Options select forms (``--form``), effects (``--effect``), the voltage column
(``--voltage without|with|both``), the noise (``--noise-ma``) and record lengths.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / 'tests'))

from common import git_commit  # noqa: E402
from datagen.electronics import FORMS  # noqa: E402
from datagen.operation import write_operation_record  # noqa: E402

#: Forms in priority order (the form to identify first, the generator's default late).
FORM_ORDER = ('dip_rise_pi_fast_cap_peak', 'timer_hysteresis_zener',
              'threshold_pwm_freewheel', 'suite_like', 'generator_default',
              'dip_pi_slow_cap_unblocked')
#: Effects in priority order.
EFFECT_ORDER = ('none', 'eddy_current', 'leakage_inductance', 'end_stop_bounce',
                'coil_heating', 'magnetic_saturation')
FIT_SEED, VALIDATE_SEED = 11, 12


@dataclass
class Cell:
    """One identification run and what its report said."""

    form: str
    effect: str
    voltage: bool
    named: str = ''
    confidence: str = ''
    base_val_nrmse_pct: float | None = None
    base_val_rmse_ma: float | None = None
    aug_val_nrmse_pct: float | None = None
    aug_val_rmse_ma: float | None = None
    noise_est_ma: float | None = None
    structured_ma: float | None = None
    unexplained: bool | None = None
    at_bound: str = ''
    route: str = ''
    generate_s: float = 0.0
    identify_s: float = 0.0
    exit_code: int | None = None
    error: str = ''


def _priority(forms: list[str], effects: list[str], voltages: list[bool]
              ) -> list[tuple[str, str, bool]]:
    """Cells in the order they run: every (effect, form) without the column, effect by
    effect, then with it; the first cell's counterpart with the column runs second (does
    the column change the answer at all)."""
    order = [(f, e, v) for v in voltages for e in effects for f in forms]
    if len(voltages) == 2:
        first = order[0]
        twin = (first[0], first[1], not first[2])
        order.remove(twin)
        order.insert(1, twin)
    return order


def _strip_voltage(src: Path, dst: Path) -> None:
    """Copy an operation CSV without its last column (``coil_voltage_mean``)."""
    out = []
    for line in src.read_text(encoding='utf-8').splitlines():
        out.append(line if line.startswith('#') else line.rsplit(',', 1)[0])
    dst.write_text('\n'.join(out) + '\n', encoding='utf-8')


def _records(work: Path, form: str, effect: str, args: argparse.Namespace
             ) -> tuple[dict[bool, tuple[Path, Path]], float]:
    """Fit and validation records of one (form, effect), with and without the column."""
    folder = work / 'records' / form / effect
    paths = {True: (folder / 'fit_v.csv', folder / 'validate_v.csv'),
             False: (folder / 'fit.csv', folder / 'validate.csv')}
    if all(p.exists() for pair in paths.values() for p in pair):
        return paths, 0.0
    start = time.perf_counter()
    for (stem, seed, duration) in (('fit_v', FIT_SEED, args.fit_s),
                                   ('validate_v', VALIDATE_SEED, args.validate_s)):
        write_operation_record(folder, stem, seed=seed, effect=effect,
                               noise_a=1e-3 * args.noise_ma, duration_s=duration,
                               circuit=FORMS[form], coil_voltage_mean=True)
    _strip_voltage(paths[True][0], paths[False][0])
    _strip_voltage(paths[True][1], paths[False][1])
    return paths, time.perf_counter() - start


def _identify(fit: Path, validate: Path, out: Path) -> tuple[int, float, str]:
    exe = shutil.which('valve_identify')
    cmd = [exe] if exe else [sys.executable, '-m', 'valve_model_pkg.cli.identify']
    cmd += ['--fit', str(fit), '--validate', str(validate), '--quick', '--no-plots',
            '--quiet', '--out', str(out)]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    return proc.returncode, time.perf_counter() - start, proc.stderr.strip()[-300:]


def _read_report(cell: Cell, report: Path) -> None:
    rep = json.loads(report.read_text(encoding='utf-8'))
    diag = rep['diagnosis']
    cell.named = diag['effect']
    cell.confidence = diag.get('confidence', '')
    cell.unexplained = diag.get('unexplained_structure')
    for key, block in (('base', rep['baseline']), ('aug', rep.get('augmented') or {})):
        val = block.get('validation') or {}
        if val:
            setattr(cell, f'{key}_val_nrmse_pct', val['nrmse_pct'])
            setattr(cell, f'{key}_val_rmse_ma', 1e3 * val['rmse'])
    numbers = diag.get('numbers', {})
    if numbers.get('baseline_noise_std_a') is not None:
        cell.noise_est_ma = 1e3 * numbers['baseline_noise_std_a']
    if numbers.get('baseline_validation_structured_rms_a') is not None:
        cell.structured_ma = 1e3 * numbers['baseline_validation_structured_rms_a']
    bounds = list(rep.get('baseline_at_search_bound') or [])
    bounds += list((rep.get('drive_electronics') or {}).get('at_search_bound') or [])
    cell.at_bound = ', '.join(bounds)
    cell.route = (rep.get('route') or {}).get('name', '')


def _before_rows(path: str | None) -> dict[tuple[str, str], tuple[str, str]]:
    """(form, effect) -> (named, base RMSE mA) of the cells without the voltage column in
    an earlier table of this script (``--before``)."""
    if not path or not Path(path).exists():
        return {}
    rows: dict[tuple[str, str], tuple[str, str]] = {}
    head: list[str] = []
    for line in Path(path).read_text(encoding='utf-8').splitlines():
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if cells and cells[0] == 'form':
            head = cells
        elif head and len(cells) == len(head) and not line.startswith('|---'):
            row = dict(zip(head, cells))
            if row.get('V mean') == 'no':
                rows[(row['form'], row['effect'])] = (row['named'], row['base RMSE mA'])
    return rows


def _fmt(value: float | None, spec: str) -> str:
    return '' if value is None else format(value, spec)


def _table(cells: list[Cell], pending: list[tuple[str, str, bool]], meta: dict[str, str],
           args: argparse.Namespace) -> str:
    lines = [f'# {args.title}', '']
    lines += [f'- {k}: {v}' for k, v in meta.items()]
    lines += ['', 'Forms (tests/datagen/electronics.py):', '']
    used = sorted({c.form for c in cells} | {p[0] for p in pending})
    lines += [f'- `{f}`: {FORMS[f].summary()}' for f in used]
    lines += ['', f'Records: the paper\'s valve with the effect, a {args.fit_s:g} s fit record '
              f'and a {args.validate_s:g} s validation record (other duty schedule and noise '
              f'draw), 1 kHz interval-mean current, {args.noise_ma:g} mA Gaussian noise; '
              '"V mean" says whether the records carry `coil_voltage_mean` (same current '
              'either way). `valve_identify --fit FIT --validate VALIDATE --quick`. '
              'NRMSE and RMSE on the validation record; "noise" and "structured" are the '
              'report\'s estimates (baseline validation residual).', '',
              '| form | effect | V mean | named | confidence | base NRMSE % | base RMSE mA '
              '| aug NRMSE % | aug RMSE mA | noise mA | structured mA | at bound | route '
              '| right | time s | before: named | before: base RMSE mA |',
              '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    before = _before_rows(args.before)
    for c in cells:
        right = '' if not c.named else ('yes' if c.named == c.effect else 'NO')
        named = c.named or f'failed ({c.exit_code}): {c.error[-80:]}'
        conf = c.confidence + (', structure left' if c.unexplained else '')
        lines.append(
            f'| {c.form} | {c.effect} | {"yes" if c.voltage else "no"} | {named} '
            f'| {conf} | {_fmt(c.base_val_nrmse_pct, ".2f")} '
            f'| {_fmt(c.base_val_rmse_ma, ".2f")} | {_fmt(c.aug_val_nrmse_pct, ".2f")} '
            f'| {_fmt(c.aug_val_rmse_ma, ".2f")} | {_fmt(c.noise_est_ma, ".2f")} '
            f'| {_fmt(c.structured_ma, ".2f")} | {c.at_bound} | {c.route} | {right} '
            f'| {c.identify_s:.0f} | {" | ".join(before.get((c.form, c.effect), ("", "")))} |')
    done = [c for c in cells if c.named]
    if done:
        right = sum(c.named == c.effect for c in done)
        lines += ['', f'Named right: {right} of {len(done)} runs.']
    if pending:
        lines += ['', 'Not run (time budget): ' + '; '.join(
            f'{f} / {e} / V mean {"yes" if v else "no"}' for f, e, v in pending) + '.']
    return '\n'.join(lines) + '\n'


def _load() -> str:
    try:
        return Path('/proc/loadavg').read_text().split(' ')[0]
    except OSError:
        return 'unknown'


def _rewrite(work: Path, args: argparse.Namespace) -> int:
    """The table again from the cells of an earlier run (``--table-only``)."""
    cells = [Cell(**c) for c in json.loads((work / 'cells.json').read_text(encoding='utf-8'))]
    meta: dict[str, str] = {}
    for line in Path(args.table).read_text(encoding='utf-8').splitlines():
        if line.startswith('Forms'):
            break
        if line.startswith('- ') and ': ' in line:
            key, value = line[2:].split(': ', 1)
            meta[key] = value
    voltages = {'without': [False], 'with': [True], 'both': [False, True]}[args.voltage]
    done = {(c.form, c.effect, c.voltage) for c in cells}
    pending = [o for o in _priority(args.form or [], args.effect or [], voltages)
               if o not in done]
    Path(args.table).write_text(_table(cells, pending, meta, args), encoding='utf-8')
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--out', required=True, help='work directory (records, reports)')
    parser.add_argument('--table', required=True, help='Markdown table to write')
    parser.add_argument('--form', action='append', choices=sorted(FORMS))
    parser.add_argument('--effect', action='append', choices=EFFECT_ORDER)
    parser.add_argument('--voltage', choices=('without', 'with', 'both'), default='both')
    parser.add_argument('--noise-ma', type=float, default=3.0)
    parser.add_argument('--before', help='an earlier table of this script: its cells '
                        'without the voltage column are shown beside each cell')
    parser.add_argument('--title', default='Identification through drive electronics of '
                        'other forms: before', help='heading of the table')
    parser.add_argument('--fit-s', type=float, default=2.0)
    parser.add_argument('--validate-s', type=float, default=1.5)
    parser.add_argument('--budget-min', type=float, default=90.0,
                        help='start no new cell after this many minutes')
    parser.add_argument('--table-only', action='store_true',
                        help='run nothing: rewrite --table from OUT/cells.json (and the '
                        'run facts of the table there), e.g. with --before')
    args = parser.parse_args(argv)
    work = Path(args.out)
    if args.table_only:
        return _rewrite(work, args)
    work.mkdir(parents=True, exist_ok=True)
    forms = args.form or [f for f in FORM_ORDER if f in FORMS]
    effects = args.effect or list(EFFECT_ORDER[:3])
    voltages = {'without': [False], 'with': [True], 'both': [False, True]}[args.voltage]
    order = _priority(forms, effects, voltages)
    start = time.perf_counter()
    loads = [_load()]
    meta = {'date': _dt.datetime.now().strftime('%Y-%m-%d %H:%M'),
            'code': f'git {git_commit()} (valve_model_pkg as of that commit)',
            'machine': f'{os.cpu_count()} cores, shared',
            'load (1 min) at start': loads[0]}
    cells: list[Cell] = []
    for n, (form, effect, voltage) in enumerate(order):
        if time.perf_counter() - start > 60.0 * args.budget_min:
            break
        cell = Cell(form, effect, voltage)
        paths, cell.generate_s = _records(work, form, effect, args)
        report_dir = work / 'reports' / f'{form}-{effect}-{"v" if voltage else "nov"}'
        cell.exit_code, cell.identify_s, cell.error = _identify(*paths[voltage], report_dir)
        if cell.exit_code == 0:
            _read_report(cell, report_dir / 'report.json')
        cells.append(cell)
        loads.append(_load())
        meta['load (1 min) at start, after each run'] = ', '.join(loads)
        meta['wall time'] = f'{(time.perf_counter() - start) / 60:.0f} min'
        Path(args.table).write_text(_table(cells, order[n + 1:], meta, args), encoding='utf-8')
        (work / 'cells.json').write_text(json.dumps([asdict(c) for c in cells], indent=1),
                                         encoding='utf-8')
        print(f'{form} / {effect} / V {voltage}: {cell.named or "failed"} '
              f'({cell.confidence}) in {cell.identify_s:.0f} s', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
