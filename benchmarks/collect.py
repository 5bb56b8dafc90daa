"""Merge benchmarks/results/*.json into benchmarks/results.json and the README's table.

Each bench_*.py writes ``benchmarks/results/<name>.json``: a list of records with the keys
``name, value, unit, reference_name, reference_value, ratio, target, passed, notes``.
"""
from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
START, END = '<!-- bench:start -->', '<!-- bench:end -->'


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f'{value:.4g}'
    return '' if value is None else str(value)


def _when(r: dict) -> str:
    """``2026-11-23 23:10, 0.4/0.6``: when the record was measured and the load then."""
    at = r.get('measured_at')
    if not at:
        return ''
    load = r.get('load_average') or []
    return at[:16].replace('T', ' ') + (', ' + '/'.join(f'{v:.1f}' for v in load)
                                        if load else '')


def collect() -> dict:
    records = []
    for path in sorted((HERE / 'results').glob('*.json')):
        try:
            entries = json.loads(path.read_text())
        except json.JSONDecodeError as err:
            print(f'collect: skipping {path}: {err}', file=sys.stderr)
            continue
        for entry in entries:
            entry.setdefault('suite', path.stem)
            records.append(entry)
    return {
        'generated': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
        'machine': {'python': platform.python_version(), 'platform': platform.platform(),
                    'cpus': os.cpu_count()},
        'results': records,
    }


def table(summary: dict) -> str:
    lines = ['| suite | benchmark | value | reference | ratio | target | met '
             '| measured (UTC), load |',
             '|---|---|---|---|---|---|---|---|']
    for r in summary['results']:
        ref = ''
        if r.get('reference_name'):
            ref = (f"{_fmt(r.get('reference_value'))} {r.get('unit', '')} "
                   f"({r.get('reference_name', '')})")
        met = {True: 'yes', False: '**no**'}.get(r.get('passed'), '')
        when = _when(r)
        lines.append(f"| {r['suite']} | {r['name']} | {_fmt(r.get('value'))} {r.get('unit', '')} "
                     f"| {ref} | {_fmt(r.get('ratio'))} | {r.get('target', '')} | {met} "
                     f"| {when} |")
    m = summary['machine']
    lines.append('')
    lines.append(f"Collected {summary['generated']} on {m['cpus']} CPUs, Python {m['python']} "
                 f"({m['platform']}) by `make bench` (each suite stamped when it ran, with "
                 f"the 1/5-min load average of the machine then; suites run by an older "
                 f"version carry no stamp); raw figures in `benchmarks/results.json`.")
    return '\n'.join(lines)


def main() -> int:
    summary = collect()
    (HERE / 'results.json').write_text(json.dumps(summary, indent=2) + '\n')
    readme = ROOT / 'README.md'
    text = readme.read_text() if readme.exists() else ''
    if START in text and END in text:
        head, rest = text.split(START, 1)
        _, tail = rest.split(END, 1)
        readme.write_text(f'{head}{START}\n{table(summary)}\n{END}{tail}')
    print(table(summary))
    return 0


if __name__ == '__main__':
    sys.exit(main())
