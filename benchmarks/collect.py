"""Merge benchmarks/results/*.json into benchmarks/results.json and write docs/benchmarks.md.

Each bench_*.py writes ``benchmarks/results/<suite>.json``: a list of records with the keys
``name, value, unit, reference_name, reference_value, ratio, target, passed, notes`` and
``measured_at`` (UTC, ISO 8601) and ``load_average`` (1 and 5 min), stamped by the bench
script (``common.write_results``) or, for one that does not stamp, by ``run_all.py`` when
the script ends. docs/benchmarks.md is generated from results.json alone: every figure
with the date it was measured and the machine load then, no empty cell, nothing typed by
hand.

Usage: python benchmarks/collect.py   (``make bench`` runs it after the benchmarks)
"""
from __future__ import annotations

import ast
import json
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS_DIR = HERE / 'results'
SUMMARY = HERE / 'results.json'
PAGE = ROOT / 'docs' / 'benchmarks.md'

#: What a cell says when the run has no figure for it.
NOT_MEASURED = 'not measured in this run'
NOT_STAMPED = 'date and load not recorded'
NO_REFERENCE = 'no reference'


def collect(results_dir: Path = RESULTS_DIR) -> dict:
    """Every record of every ``results/<suite>.json``, with the machine that collected them.

    A file that is not valid JSON is named on stderr and left out.
    """
    records = []
    for path in sorted(results_dir.glob('*.json')):
        try:
            entries = json.loads(path.read_text(encoding='utf-8'))
        except json.JSONDecodeError as err:
            print(f'collect: {path}: not valid JSON ({err}); left out', file=sys.stderr)
            continue
        for entry in entries:
            entry.setdefault('suite', path.stem)
            records.append(entry)
    return {
        'generated': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        'machine': {'python': platform.python_version(), 'platform': platform.platform(),
                    'cpus': os.cpu_count()},
        'results': records,
    }


def fmt_number(value: object) -> str:
    """A figure as the page prints it: 4 significant digits for floats."""
    if isinstance(value, float):
        return f'{value:.4g}'
    return str(value)


def when(record: dict) -> str:
    """``YYYY-MM-DD HH:MM UTC, load 0.4/0.6``: when the record was measured, the load then."""
    at = record.get('measured_at')
    if not at:
        return NOT_STAMPED
    load = record.get('load_average') or []
    text = at[:16].replace('T', ' ') + ' UTC'
    if load:
        text += ', load ' + '/'.join(f'{v:.1f}' for v in load)
    else:
        text += ', load not recorded'
    return text


@dataclass(frozen=True)
class Row:
    """One record as the page's table shows it; every cell has text."""

    name: str
    value: str
    reference: str
    ratio: str
    target: str
    met: str


def row(record: dict) -> Row:
    """The cells of one record (no empty cell: a missing figure is said in words)."""
    unit = record.get('unit') or ''
    value = record.get('value')
    target = str(record.get('target') or 'none stated')
    if value is None:
        shown = (f'no figure ({target})' if target.startswith('flag:') else NOT_MEASURED)
    else:
        shown = f'{fmt_number(value)} {unit}'.strip()
    ref_name = record.get('reference_name')
    if ref_name == 'target' and record.get('reference_value') is None:
        ref_name = None     # a target without a number: nothing to compare with
    if ref_name:
        ref_value = record.get('reference_value')
        ref_text = NOT_MEASURED if ref_value is None else f'{fmt_number(ref_value)} {unit}'
        reference = f'{ref_text.strip()} ({ref_name})'
    else:
        reference = NO_REFERENCE
    ratio = record.get('ratio')
    ratio_text = fmt_number(ratio) if ratio is not None else (
        NOT_MEASURED if ref_name else NO_REFERENCE)
    met = {True: 'yes', False: '**no**'}.get(record.get('passed'), 'not judged')
    return Row(record['name'], shown, reference, ratio_text, target, met)


def previous(record: dict) -> str:
    """The figure of the same name before this run, with its date and load, or a dash."""
    before = record.get('previous')
    if not before or before.get('value') is None:
        return '-'
    shown = f"{fmt_number(before['value'])} {record.get('unit') or ''}".strip()
    return f'{shown} ({when(before)})'


def _cell(text: str) -> str:
    return text.replace('|', '\\|').replace('\n', ' ')


def suite_description(suite: str, bench_dir: Path = HERE) -> str:
    """The first line of ``bench_<suite>.py``'s docstring."""
    script = bench_dir / f'bench_{suite}.py'
    if not script.exists():
        return f'(no benchmarks/bench_{suite}.py: results from an older run)'
    doc = ast.get_docstring(ast.parse(script.read_text(encoding='utf-8'))) or ''
    first = doc.strip().splitlines()[0] if doc.strip() else f'bench_{suite}.py'
    return first.rstrip(' .:') + '.'


def suite_section(suite: str, records: list[dict]) -> list[str]:
    """``## suite``: what it measures, when, and its table (with a date column if mixed)."""
    stamps = {when(r) for r in records}
    lines = [f'## {suite}', '', f'`benchmarks/bench_{suite}.py`: {suite_description(suite)}',
             '']
    one_stamp = len(stamps) == 1
    if one_stamp:
        stamp = stamps.pop()
        lines += [f'Measured {stamp} (1/5-min load average).' if stamp != NOT_STAMPED
                  else f'{NOT_STAMPED.capitalize()} for this run of the suite.', '']
    head = ['benchmark', 'value', 'reference', 'ratio', 'target', 'met']
    if not one_stamp:
        head.append('measured, load')
    with_previous = any(r.get('previous') for r in records)
    if with_previous:
        head.append('previous run')
    lines += ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for record in records:
        r = row(record)
        cells = [r.name, r.value, r.reference, r.ratio, r.target, r.met]
        if not one_stamp:
            cells.append(when(record))
        if with_previous:
            cells.append(previous(record))
        lines.append('| ' + ' | '.join(_cell(c) for c in cells) + ' |')
    lines.append('')
    notes = [(record['name'], record.get('notes')) for record in records if record.get('notes')]
    if notes:
        lines += ['Notes:', '']
        lines += [f'- `{_cell(name)}`: {_cell(str(text))}' for name, text in notes]
        lines.append('')
    return lines


def page(summary: dict) -> str:
    """docs/benchmarks.md: an introduction and one section per suite."""
    m = summary['machine']
    suites: dict[str, list[dict]] = {}
    for record in summary['results']:
        suites.setdefault(record['suite'], []).append(record)
    lines = [
        '# Benchmarks',
        '',
        '<!-- Generated by benchmarks/collect.py from benchmarks/results.json; do not edit. '
        'Run `make bench` (all) or `python benchmarks/run_all.py SUITE ...` (some). -->',
        '',
        '`make bench` runs every `benchmarks/bench_*.py` in its own process, each against a '
        'reference measured in the same run where there is one, then the demos '
        '([demo.md](demo.md)), and writes `benchmarks/results.json` and this page. '
        '`python benchmarks/run_all.py model map` runs some suites only; the others keep '
        'their last figures, each with the date it was measured and the machine\'s '
        '1/5-minute load average then. The machine is shared: read a figure with its load.',
        '',
        '"met" says whether the figure met the target in that run; "not judged" marks an '
        'informative figure. A figure a run did not produce says so in words. Where a suite '
        'keeps the figures its results file held before the run, "previous run" shows them '
        'beside the new ones, with their date and load.',
        '',
        f'Collected {summary["generated"][:16].replace("T", " ")} UTC on {m["cpus"]} CPUs, '
        f'Python {m["python"]} ({m["platform"]}).',
        '',
        'Suites: ' + ', '.join(f'[{s}](#{s})' for s in suites) + '.',
        '',
    ]
    for suite, records in suites.items():
        lines += suite_section(suite, records)
    return '\n'.join(lines).rstrip('\n') + '\n'


def main() -> int:
    summary = collect()
    SUMMARY.write_text(json.dumps(summary, indent=2) + '\n', encoding='utf-8')
    PAGE.write_text(page(summary), encoding='utf-8')
    print(f'collect: {len(summary["results"])} figures -> {SUMMARY.relative_to(ROOT)}, '
          f'{PAGE.relative_to(ROOT)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
