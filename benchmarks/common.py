"""What every benchmark shares: the result record, the machine's load, the results file.

Each ``bench_*.py`` writes ``benchmarks/results/<suite>.json``: a list of records with the
keys ``name, value, unit, reference_name, reference_value, ratio, target, passed, notes``
plus ``measured_at`` (UTC, ISO 8601) and ``load_average`` (1 and 5 min when the file was
written) so that docs/benchmarks.md (``collect.py``) says when, and under what load, each
suite was measured (suites are often run at different times).
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import subprocess
import time
from pathlib import Path

RESULTS_DIR = Path(__file__).resolve().parent / 'results'
ROOT = Path(__file__).resolve().parent.parent


def git_commit() -> str:
    """The short hash of the checked-out commit ('unknown' outside a git work tree)."""
    try:
        return subprocess.run(['git', '-C', str(ROOT), 'rev-parse', '--short', 'HEAD'],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return 'unknown'


def provenance_lines() -> list[str]:
    """The list items a hand-run benchmark's Markdown page starts with: when (local time),
    which code, what machine."""
    return [f'- date: {_dt.datetime.now().strftime("%Y-%m-%d %H:%M")}',
            f'- code: git {git_commit()}', f'- machine: {os.cpu_count()} cores, shared']


def record(name: str, value: float | None, unit: str, ref_name: str | None,
           ref_value: float | None, target: str, passed: bool | None, notes: str,
           ratio: float | None = None) -> dict:
    """One benchmark result.

    ``ratio`` defaults to value / reference (None without a reference or a value); pass it
    explicitly when the comparison runs the other way (e.g. a speed-up from two times).
    """
    if ratio is None and ref_value and value is not None:
        ratio = value / ref_value
    return {'name': name, 'value': value, 'unit': unit, 'reference_name': ref_name,
            'reference_value': ref_value, 'ratio': ratio, 'target': target,
            'passed': passed, 'notes': notes}


def load_text() -> str:
    """The machine's load as notes quote it: ``load average 0.4/0.6 (1/5 min) on 2 CPUs``."""
    one, five, _ = os.getloadavg()
    return f'load average {one:.1f}/{five:.1f} (1/5 min) on {os.cpu_count()} CPUs'


def write_results(suite: str, records: list[dict]) -> Path:
    """Write ``results/<suite>.json``, stamping each record with the time and the load."""
    stamp = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())
    load = [round(v, 2) for v in os.getloadavg()[:2]]
    for r in records:
        r.setdefault('measured_at', stamp)
        r.setdefault('load_average', load)
    RESULTS_DIR.mkdir(exist_ok=True)
    out = RESULTS_DIR / f'{suite}.json'
    out.write_text(json.dumps(records, indent=1) + '\n', encoding='utf-8')
    return out
