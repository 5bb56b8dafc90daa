"""Benchmark valve_import on a 10 M-sample NI TDMS capture: time and peak memory.

A TDMS file as a DAQ writes it (one group, a voltage and a current channel of float64
with waveform properties, written in 100 k-sample segments): a 24 V step at 1 ms on an RL
coil (tau 7 ms) with 3 mA noise, 16-bit, 10 M samples at 1 MHz (10 s). ``valve_import``
runs in a process of its own (its peak resident memory is the child's ``ru_maxrss``):

1. ``--decimate auto`` (the default): 10 M samples read, 500 k rows written (20 us);
2. ``--decimate 1``: all 10 M rows written with the measured-data format's writer.

Target: peak memory below 1 GB for both. Writes benchmarks/results/import.json.

Usage: python benchmarks/bench_import.py [--samples N]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from common import load_text, record, write_results  # noqa: E402

RATE_HZ = 1e6
SEGMENT = 100_000
MEMORY_TARGET_MB = 1024.0


def write_capture(path: Path, n: int) -> None:
    """The synthetic 10 s capture, written segment by segment (bounded memory)."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
    rng = np.random.default_rng(1)
    lsb_v, lsb_i = 60.0 / 65536, 10.0 / 65536
    props = {'wf_start_offset': -1e-3, 'wf_increment': 1.0 / RATE_HZ, 'wf_samples': n}
    with TdmsWriter(str(path)) as writer:
        for a in range(0, n, SEGMENT):
            t = (np.arange(a, min(a + SEGMENT, n)) / RATE_HZ) - 1e-3
            v = np.where(t >= 0.0, 24.0, 0.0)
            i = np.where(t >= 0.0, 24.0 / 13.0 * (1.0 - np.exp(-np.maximum(t, 0) / 7e-3)), 0)
            i = i + rng.normal(0.0, 3e-3, t.size)
            head = [RootObject({}), GroupObject('Measurement', {})] if a == 0 else []
            writer.write_segment(head + [
                ChannelObject('Measurement', 'Coil voltage', np.round(v / lsb_v) * lsb_v,
                              {**props, 'unit_string': 'V'} if a == 0 else {}),
                ChannelObject('Measurement', 'Coil current', np.round(i / lsb_i) * lsb_i,
                              {**props, 'unit_string': 'A'} if a == 0 else {})])


def run_import(src: Path, out: Path, decimate: str) -> tuple[float, float, int]:
    """Wall time [s], peak RSS [MB] and exit status of one valve_import process."""
    argv = [sys.executable, '-m', 'valve_model_pkg.cli.import_record', str(src),
            '--voltage', 'Coil voltage', '--current', 'Coil current', '-o', str(out),
            '--decimate', decimate, '--supply-pressure-pa', '4e5', '--quiet']
    env = {**os.environ, 'PYTHONPATH': str(HERE.parent / 'valve_model_pkg') + os.pathsep
           + os.environ.get('PYTHONPATH', '')}
    start = time.perf_counter()
    proc = subprocess.Popen(argv, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - start
    return elapsed, usage.ru_maxrss / 1024.0, os.waitstatus_to_exitcode(status)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--samples', type=int, default=10_000_000)
    args = parser.parse_args(argv)
    n = args.samples
    records = []
    with tempfile.TemporaryDirectory(prefix='bench_import_') as tmp:
        src = Path(tmp) / 'capture.tdms'
        start = time.perf_counter()
        write_capture(src, n)
        size_mb = src.stat().st_size / 1e6
        print(f'wrote {src} ({size_mb:.0f} MB) in {time.perf_counter() - start:.1f} s',
              file=sys.stderr)
        for decimate, rows in (('auto', n // 20), ('1', n)):
            out = Path(tmp) / f'record_{decimate}.csv'
            elapsed, peak_mb, code = run_import(src, out, decimate)
            load = load_text()
            out_mb = out.stat().st_size / 1e6 if out.exists() else 0.0
            print(f'decimate {decimate}: exit {code}, {elapsed:.1f} s, peak {peak_mb:.0f} MB, '
                  f'{out_mb:.0f} MB written; {load}', file=sys.stderr)
            note = (f'{n} samples x 2 channels ({size_mb:.0f} MB TDMS) -> about {rows} rows '
                    f'({out_mb:.0f} MB CSV); exit {code}; {load}')
            records.append(record(f'valve_import 10M-sample TDMS, --decimate {decimate}: time',
                                  elapsed, 's', None, None, 'reported', code == 0, note))
            records.append(record(
                f'valve_import 10M-sample TDMS, --decimate {decimate}: peak memory', peak_mb,
                'MB', 'memory target', MEMORY_TARGET_MB, '< 1024 MB',
                code == 0 and peak_mb < MEMORY_TARGET_MB, note))
            out.unlink(missing_ok=True)
    path = write_results('import', records)
    print(f'wrote {path}', file=sys.stderr)
    return 0 if all(r['passed'] for r in records) else 1


if __name__ == '__main__':
    sys.exit(main())
