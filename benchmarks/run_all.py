"""`make bench`: every benchmarks/bench_*.py in its own process, the demos, then the pages.

Usage: python benchmarks/run_all.py [NAME ...]
  NAME = model, map, can, ... picks those suites; ``demo`` the demos (demo_page.py). With
  no NAME everything runs. The other suites keep their last figures.

After each suite its results file is stamped where the script did not stamp it itself
(``measured_at`` = when the script ended, ``load_average`` = the load when it started), so
every figure on docs/benchmarks.md has its date and load. Then collect.py writes
benchmarks/results.json and docs/benchmarks.md, and demo_page.py docs/demo.md.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS_DIR = HERE / 'results'


def stamp_results(path: Path, measured_at: str, load_average: list[float]) -> int:
    """Add ``measured_at`` and ``load_average`` to the records of ``path`` that lack them.

    Returns the number of records stamped (0 if the file is missing or not a list).
    """
    if not path.is_file():
        return 0
    try:
        records = json.loads(path.read_text(encoding='utf-8'))
    except json.JSONDecodeError:
        return 0        # collect.py names the file
    if not isinstance(records, list):
        return 0
    stamped = 0
    for record in records:
        if isinstance(record, dict) and not record.get('measured_at'):
            record['measured_at'] = measured_at
            record['load_average'] = load_average
            stamped += 1
    if stamped:
        path.write_text(json.dumps(records, indent=1) + '\n', encoding='utf-8')
    return stamped


def run_suite(script: Path) -> int:
    """Run one bench script; stamp what it wrote; return its exit code."""
    print(f'== {script.name}', flush=True)
    results = RESULTS_DIR / (script.stem.removeprefix('bench_') + '.json')
    before = results.stat().st_mtime if results.exists() else None
    load = [round(v, 2) for v in os.getloadavg()[:2]]
    start = time.monotonic()
    code = subprocess.call([sys.executable, str(script)], cwd=HERE.parent)
    print(f'== {script.name}: exit {code} after {time.monotonic() - start:.1f} s', flush=True)
    if results.exists() and results.stat().st_mtime != before:
        stamp_results(results, time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()), load)
    return code


def main(argv: list[str]) -> int:
    wanted = set(argv)
    scripts = [p for p in sorted(HERE.glob('bench_*.py'))
               if not wanted or p.stem.removeprefix('bench_') in wanted]
    known = {p.stem.removeprefix('bench_') for p in HERE.glob('bench_*.py')} | {'demo'}
    unknown = sorted(wanted - known)
    if unknown:
        print(f'run_all.py: error: unknown benchmark {unknown[0]!r} (known: '
              f'{", ".join(sorted(known))})', file=sys.stderr)
        return 2
    failed = [script.name for script in scripts if run_suite(script) != 0]
    subprocess.check_call([sys.executable, str(HERE / 'collect.py')])
    demo_args = [] if not wanted or 'demo' in wanted else ['--page-only']
    if subprocess.call([sys.executable, str(HERE / 'demo_page.py'), *demo_args]) != 0:
        failed.append('demo_page.py')
    if failed:
        print('benchmarks that failed to run: ' + ', '.join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
