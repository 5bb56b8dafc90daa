"""Fleet identification benchmark: scaling from 1 to 2 local workers.

Writes benchmarks/results/fleet.json (records: name, value, unit, reference_name,
reference_value, ratio, target, passed, notes).

The same manifest is run by ``valve_identify_batch`` (as a user runs it: a new process, the
worker pool's start-up and the numba cache loading counted) with ``--workers 1`` and
``--workers 2``, each into a fresh output folder; the wall time of each and the speed-up
``t(1) / t(2)`` are recorded, for two workloads:

1. ``baseline``: 8 valves (``none`` case, seeds 1-8, 20 ms records), baseline fit only
   (``--quick --no-diagnosis``): one valve is one thread's work, the pool is all the
   parallelism there is; target speed-up >= 1.6 on 2 cores.
2. ``close_the_loop``: 4 valves with the effect search (``--quick``): the identification
   already runs its candidate refits on threads of its own, so one worker uses both cores
   for part of each valve; informative.
"""
from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from common import record as _record, write_results  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / 'tests'))

from datagen.generate import generate_case  # noqa: E402

WORKLOADS = {
    'baseline': {'valves': 8, 'options': ['--quick', '--no-diagnosis'], 'target': 1.6},
    'close_the_loop': {'valves': 4, 'options': ['--quick'], 'target': None},
}


def _manifest(root: Path, n: int) -> Path:
    lines = ['valve_id,fit,validate']
    for seed in range(1, n + 1):
        truth = generate_case(root / f'v{seed:02d}', 'none', seed=seed, step_duration_s=0.02)
        lines.append(f'V{seed:02d},{truth["fit"][0]},{truth["validate"][0]}')
    path = root / f'fleet{n}.csv'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return path


def _run(manifest: Path, out: Path, workers: int, options: list[str]) -> tuple[float, float]:
    """Wall time and CPU time (user + system, the command and its workers) of one run, s."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / 'valve_model_pkg'), os.environ.get('PYTHONPATH', '')]))
    cmd = [sys.executable, '-m', 'valve_model_pkg.cli.identify_batch', str(manifest),
           '-o', str(out), '--workers', str(workers), '--no-plots', '--quiet', *options]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if proc.returncode != 0:
        raise RuntimeError(f'{" ".join(cmd)} exited {proc.returncode}: {proc.stderr}')
    return wall, cpu


def main() -> int:
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        # Warm the numba cache once, so neither timed run pays a compilation.
        warm = _manifest(root / 'warm', 1)
        _run(warm, root / 'warm-out', 1, ['--quick', '--no-diagnosis'])
        for name, w in WORKLOADS.items():
            manifest = _manifest(root / name, w['valves'])
            load = (f'machine load average {os.getloadavg()[0]:.1f} before, on '
                    f'{os.cpu_count()} CPUs')
            t1, c1 = _run(manifest, root / f'{name}-1', 1, w['options'])
            t2, c2 = _run(manifest, root / f'{name}-2', 2, w['options'])
            speedup = t1 / t2
            cpu = (f'CPU time (user + system) 1 worker {c1:.1f} s, 2 workers {c2:.1f} s '
                   f'(cores busy on average: {c1 / t1:.2f} and {c2 / t2:.2f})')
            print(f'{name}: {w["valves"]} valves, 1 worker {t1:.1f} s, 2 workers {t2:.1f} s, '
                  f'speed-up {speedup:.2f}; {cpu}', file=sys.stderr)
            target = w['target']
            notes = (f'{w["valves"]} valves, 20 ms records, valve_identify_batch '
                     f'{" ".join(w["options"])} --no-plots, wall time of the whole command; '
                     f'{cpu}; {load}')
            records.append(_record(
                f'fleet_{name}_{w["valves"]}_valves_2_workers', t2, 's', '1 worker', t1,
                'informative', None, notes))
            records.append(_record(
                f'fleet_{name}_speedup_1_to_2_workers', speedup, 'x', None, None,
                f'>= {target}' if target else 'informative',
                (speedup >= target) if target else None,
                f'1 worker {t1:.1f} s, 2 workers {t2:.1f} s; {notes}'))
    write_results('fleet', records)
    return 0


if __name__ == '__main__':
    sys.exit(main())
