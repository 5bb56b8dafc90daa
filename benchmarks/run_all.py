"""`make bench`: run every benchmarks/bench_*.py in its own process, then collect.

Usage: python benchmarks/run_all.py [NAME ...]   (NAME = model, map, can, ... to pick some)
"""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    wanted = set(argv)
    scripts = [p for p in sorted(HERE.glob('bench_*.py'))
               if not wanted or p.stem.removeprefix('bench_') in wanted]
    failed = []
    for script in scripts:
        print(f'== {script.name}', flush=True)
        start = time.monotonic()
        code = subprocess.call([sys.executable, str(script)], cwd=HERE.parent)
        print(f'== {script.name}: exit {code} after {time.monotonic() - start:.1f} s', flush=True)
        if code != 0:
            failed.append(script.name)
    subprocess.check_call([sys.executable, str(HERE / 'collect.py')])
    if failed:
        print('benchmarks that failed to run: ' + ', '.join(failed), file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
