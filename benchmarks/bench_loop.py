"""The whole loop, both modes, as a user runs it.

Writes benchmarks/results/loop.json (records: name, value, unit, reference_name,
reference_value, ratio, target, passed, notes, measured_at, load_average).

Runs ``valve_bench_loop`` in a fresh process per configuration, one after the other:

* ``--mode bench`` (bare-coil 24 V / 15 V steps over CAN, coil heating on the emulated
  valve) and ``--mode operation`` (the suite's own position-control run, eddy current on
  the emulated valve), each in the test configuration (``--quick``, target <= 3 min on 2
  cores) and at full length (no ``--quick``: informative);
* the wall time of the whole command, the time split (bench: the identification's
  ``timings_s``; operation: ``loop.json`` ``stages_s``) and the answers (effect named,
  validation error before/after, tracking before/after) in the notes; for the operation
  loop also records of the tracking and flow prediction error after vs before and of the
  calibrated flow area at full opening vs the valve in service.

Usage: python benchmarks/bench_loop.py [--configs quick full] [--modes bench operation]
(all four: about 15 minutes on 2 quiet cores).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from common import load_text, record, write_results  # noqa: E402

#: The test configuration's target [s].
TARGET_S = 180.0


def _answers(mode: str, out: Path) -> tuple[str, str]:
    """(the split, the answers) of a finished loop in ``out``."""
    if mode == 'operation':
        loop = json.loads((out / 'loop.json').read_text(encoding='utf-8'))
        split = ', '.join(f'{k} {v:.0f} s' for k, v in loop['stages_s'].items())
        tr = loop['tracking']
        ans = (f"effect named {loop['diagnosis'].get('effect')} "
               f"({loop['diagnosis'].get('confidence')}), validation IAE "
               f"{loop['baseline']['validation']['iae']:.4g} -> "
               f"{loop['augmented']['validation']['iae']:.4g} A s, tracking "
               f"{tr['before']['rms_mm']:.3f} -> {tr['after']['rms_mm']:.3f} mm RMS")
        return split, ans
    rep = json.loads((out / 'identification' / 'report.json').read_text(encoding='utf-8'))
    split = 'identification: ' + ', '.join(f'{k} {v:.0f} s'
                                           for k, v in rep.get('timings_s', {}).items())
    d = rep['diagnosis']
    ans = (f"effect named {d.get('effect')} ({d.get('confidence')}), validation RMSE "
           f"{1e3 * rep['baseline']['validation']['rmse']:.2f} -> "
           f"{1e3 * rep['augmented']['validation']['rmse']:.2f} mA")
    return split, ans


def run_one(mode: str, quick: bool, tmp: Path) -> dict:
    out = tmp / f'{mode}_{"quick" if quick else "full"}'
    cmd = ['valve_bench_loop', '--mode', mode, '--out', str(out)]
    if quick:
        cmd.append('--quick')
    load_before = load_text()
    t0 = time.monotonic()
    proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wall = time.monotonic() - t0
    label = 'test configuration (--quick)' if quick else 'full length'
    name = f'loop_{mode}_{"quick" if quick else "full"}_wall'
    if proc.returncode != 0:
        tail = ' | '.join(proc.stdout.strip().splitlines()[-3:])
        return record(name, wall, 's', 'target', TARGET_S if quick else None,
                      '<= 180 s on 2 cores' if quick else 'informative', False,
                      f'valve_bench_loop --mode {mode} ({label}) FAILED with exit '
                      f'{proc.returncode}: {tail}; {load_before} before')
    split, ans = _answers(mode, out)
    return record(name, wall, 's', 'target', TARGET_S if quick else None,
                  '<= 180 s on 2 cores' if quick else 'informative',
                  (wall <= TARGET_S) if quick else None,
                  f'valve_bench_loop --mode {mode} ({label}), whole command: {ans}; time '
                  f'split: {split}; {load_before} before, {load_text()} after')


def operation_answers(quick: bool, out: Path) -> list[dict]:
    """The operation loop's results as records: tracking and flow error after vs before
    (tracking not worse), the flow area at full opening vs the valve in service."""
    loop = json.loads((out / 'loop.json').read_text(encoding='utf-8'))
    tag = 'quick' if quick else 'full'
    tr, fl = loop['tracking'], loop['flow']
    cal = loop.get('flow_calibration') or {}
    why = (f"effect {loop['effect_injected']} named {loop['diagnosis'].get('effect')}; "
           f"valve in service C_d {loop['plant']['discharge_coefficient']:g} (suite 0.8)")
    recs = [
        record(f'loop_operation_{tag}_tracking_rms', tr['after']['rms_mm'], 'mm',
               'before', tr['before']['rms_mm'], 'after < before', None, why),
        record(f'loop_operation_{tag}_flow_error', fl['after']['rms_pct'], '% of full flow',
               'before', fl['before']['rms_pct'], 'after < before', None,
               why + '; measured by the chamber mass balance, 0.1 s windows, after run')]
    for r in recs:
        r['passed'] = r['value'] < r['reference_value']
    if 'full_opening_error_pct' in cal:
        recs.append(record(f'loop_operation_{tag}_full_opening_area_error',
                           cal['full_opening_error_pct'], '%', 'suite\'s set',
                           cal['suite_full_opening_error_pct'], 'informative', None,
                           why + '; C_d C_A x stroke of the set in force vs the valve in '
                           'service'))
    return recs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--configs', nargs='+', choices=('quick', 'full'),
                        default=['quick', 'full'])
    parser.add_argument('--modes', nargs='+', choices=('bench', 'operation'),
                        default=['bench', 'operation'])
    args = parser.parse_args(argv)
    records = []
    with tempfile.TemporaryDirectory(prefix='bench_loop_') as tmp:
        for mode in args.modes:
            for config in args.configs:
                print(f'bench_loop: {mode} ({config}) ...', file=sys.stderr, flush=True)
                r = run_one(mode, config == 'quick', Path(tmp))
                print(f"  {r['value']:.0f} s: {r['notes']}", file=sys.stderr, flush=True)
                records.append(r)
                out = Path(tmp) / f'operation_{config}'
                if mode == 'operation' and (out / 'loop.json').exists():
                    records += operation_answers(config == 'quick', out)
    write_results('loop', records)
    return 0 if all(r['passed'] is not False or 'FAILED' not in r['notes']
                    for r in records) else 1


if __name__ == '__main__':
    sys.exit(main())
