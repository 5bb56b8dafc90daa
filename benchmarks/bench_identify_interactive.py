"""Identification at interactive speed: the three targets, each on one core.

Writes benchmarks/results/identify_interactive.json (records: name, value, unit,
reference_name, reference_value, ratio, target, passed, notes, measured_at, load_average,
and ``previous``: the record of the same name the file held before, so a run shows its
figures next to the last ones).

The process is pinned to one CPU, numba and BLAS to one thread, and the identification
runs with ``IdentifySettings(threads=1)``; the kernels are loaded by an untimed quick run
first. The notes also give the process's CPU time of each run: on a loaded machine the
pinned CPU is shared, and the CPU time is what the run takes on a quiet core.

1. ``identify_step_pair_40ms_one_core``: the whole loop (baseline, signatures, refits,
   selection) on a 24 V fit and a 15 V validation step, 40 ms at 50 kHz from the
   independent truth model (tests/datagen, case ``eddy_current``, seed 5: an effect to
   find, so every stage runs), default effort; target <= 10 s.
2. ``identify_operation_10s_1khz_one_core``: the whole loop on a 10 s operational record
   at 1 kHz through the drive electronics (interval means, 3 mA noise, the suite's own
   model; the last 30 % held out), default effort; target <= 30 s.
3. ``identify_loop_in_service_one_core``: the identification part of
   ``valve_bench_loop --mode operation`` (default length), i.e. ``valve_identify --fit``
   on the loop's bag of the valve in service; target <= 60 s. The loop is run first
   (minutes, ROS) unless ``--loop-bag BAG`` names a bag of an earlier run; ``--only``
   without ``loop`` leaves it out.

Usage: python benchmarks/bench_identify_interactive.py [--only step ops loop]
       [--loop-bag BAG]
"""
from __future__ import annotations

import os

for _name in ('NUMBA_NUM_THREADS', 'OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS',
              'MKL_NUM_THREADS'):
    os.environ[_name] = '1'

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / 'valve_model_pkg'))
sys.path.insert(0, str(ROOT / 'tests'))
sys.path.insert(0, str(HERE))

from common import RESULTS_DIR, load_text, record, write_results  # noqa: E402

SUITE = 'identify_interactive'
TARGETS_S = {'step': 10.0, 'ops': 30.0, 'loop': 60.0}


def _pin_one_cpu() -> int:
    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return cpu


def _timed(name: str, what: str, fit: list, validate: list, target_s: float) -> dict:
    from valve_model_pkg.identification import IdentifySettings, identify
    load = load_text()
    t0, c0 = time.perf_counter(), time.process_time()
    ident = identify(fit, validate, IdentifySettings(threads=1))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    d = ident.diagnosis
    split = ', '.join(f'{k} {v:.1f} s' for k, v in ident.timings_s.items())
    notes = (f'{what}; diagnosis {d.effect} ({d.confidence}); {ident.simulations} '
             f'simulations; {cpu:.1f} s of CPU time (the wall time on a quiet core); time '
             f'split: {split}; one core; {load} before')
    print(f'{name}: {wall:.1f} s ({cpu:.1f} s CPU), {d.effect} ({d.confidence}), '
          f'{ident.simulations} simulations', file=sys.stderr, flush=True)
    return record(name, wall, 's', 'target', target_s, f'<= {target_s:g} s on one core',
                  wall <= target_s, notes)


def _warm_up(tmp: Path) -> None:
    """Load the kernels (bare coil and drive electronics) outside the timed runs."""
    from bench_identify import _write_operation
    from datagen.generate import generate_case
    from valve_model_pkg.identification import IdentifySettings, identify
    from valve_model_pkg.model import load_parameters
    case = generate_case(tmp / 'warm', 'none', seed=2, step_duration_s=0.02)
    quick = IdentifySettings(quick=True, diagnose=False, threads=1)
    identify(case['fit'], case['validate'], quick)
    identify([_write_operation(tmp / 'warm.csv', load_parameters(), 0.5, 3e-3, 3)], [], quick)


def _step(tmp: Path) -> dict:
    from datagen.generate import generate_case
    case = generate_case(tmp / 'steps', 'eddy_current', seed=5)
    return _timed('identify_step_pair_40ms_one_core', 'tests/datagen eddy_current seed 5: '
                  '24 V fit and 15 V validation steps, 40 ms at 50 kHz, bench noise',
                  case['fit'], case['validate'], TARGETS_S['step'])


def _ops(tmp: Path) -> dict:
    from bench_identify import _write_operation
    from valve_model_pkg.model import load_parameters
    rec = _write_operation(tmp / 'ops10.csv', load_parameters(), 10.0, 3e-3, 1)
    return _timed('identify_operation_10s_1khz_one_core', '10 s operational record at 1 kHz '
                  '(suite model, 3 mA noise), last 30 % held out', [rec], [],
                  TARGETS_S['ops'])


def _loop_bag(tmp: Path) -> Path:
    """Run ``valve_bench_loop --mode operation`` and return its bag before the loop."""
    out = tmp / 'loop'
    subprocess.run(['valve_bench_loop', '--mode', 'operation', '-o', str(out)], check=True,
                   stdout=subprocess.DEVNULL)
    return next(p for p in sorted((out / 'before').iterdir())
                if (p / 'metadata.yaml').exists())


def _loop(tmp: Path, bag: Path | None) -> dict:
    bag = bag or _loop_bag(tmp)
    return _timed('identify_loop_in_service_one_core', f'valve_identify --fit on the bag of '
                  f'valve_bench_loop --mode operation ({bag.name})', [bag], [],
                  TARGETS_S['loop'])


def _with_previous(records: list[dict]) -> list[dict]:
    """``records`` plus the file's records not measured now; each new record carries the
    file's record of the same name as ``previous``."""
    path = RESULTS_DIR / f'{SUITE}.json'
    old = json.loads(path.read_text(encoding='utf-8')) if path.exists() else []
    by_name = {r['name']: r for r in old}
    for r in records:
        before = by_name.pop(r['name'], None)
        if before is not None:
            r['previous'] = {k: before.get(k) for k in ('value', 'measured_at',
                                                        'load_average', 'notes')}
    return records + list(by_name.values())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--only', nargs='+', choices=('step', 'ops', 'loop'),
                   default=['step', 'ops', 'loop'])
    p.add_argument('--loop-bag', type=Path, default=None,
                   help='bag of an earlier valve_bench_loop --mode operation run')
    args = p.parse_args(argv)
    cpu = _pin_one_cpu()
    print(f'pinned to CPU {cpu}; {load_text()}', file=sys.stderr, flush=True)
    records = []
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        _warm_up(tmp)
        if 'step' in args.only:
            records.append(_step(tmp))
        if 'ops' in args.only:
            records.append(_ops(tmp))
        if 'loop' in args.only:
            records.append(_loop(tmp, args.loop_bag))
    write_results(SUITE, _with_previous(records))
    return 0


if __name__ == '__main__':
    sys.exit(main())
