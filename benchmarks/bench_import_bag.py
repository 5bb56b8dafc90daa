"""Benchmark reading a 2 GB rosbag2 bag for identification: time and peak memory.

A bag as ``ros2 bag record`` writes it in Jazzy (MCAP, metadata version 9, one file) on a
machine that also records a camera: ``/camera/image_raw`` (sensor_msgs/Image, 640 x 480
rgb8, 30 Hz) fills it, while the user's firmware publishes the coil voltage and current
as std_msgs/Float32 on ``/coil/voltage`` and ``/coil/current`` at 10 kHz (24 V steps, 20 ms
on, 30 ms off, on an RL coil, tau 7 ms, 3 mA noise, 8-bit current of 16 mA steps). The
bag is written with rosbags' writer, message by message (bounded memory).

The reading is what ``valve_identify --fit BAG --map current=/coil/current --map
voltage=/coil/voltage --map supply_pressure=4e5`` does first
(:func:`valve_model_pkg.identification.read_measurements`), in a process of its own (its
peak resident memory is the child's ``ru_maxrss``): the camera's messages are passed over,
the two mapped topics become one record. Target: peak memory below 1 GB.
Writes benchmarks/results/import_bag.json.

Usage: python benchmarks/bench_import_bag.py [--size-gb G] [--keep DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from common import load_text, record, write_results  # noqa: E402

RATE_HZ = 10_000
CAMERA_HZ = 30
WIDTH, HEIGHT = 640, 480
LSB_A = 0.016
MEMORY_TARGET_MB = 1024.0
MAP = ['current=/coil/current', 'voltage=/coil/voltage', 'supply_pressure=4e5']

_READ = """
import json, sys, time
from valve_model_pkg.identification import read_measurements
from valve_model_pkg.identification.topic_map import parse_topic_map
start = time.perf_counter()
(m,) = read_measurements([sys.argv[1]], mapping=parse_topic_map(sys.argv[2:]))
print(json.dumps({'seconds': time.perf_counter() - start, 'samples': m.n_samples,
                  'duration_s': m.duration_s, 'current_lsb_a': m.current_lsb_a,
                  'experiment': m.experiment}))
"""


def _float32(value: float) -> bytes:
    """A std_msgs/Float32 in CDR (little endian): the encapsulation header and the value."""
    return b'\x00\x01\x00\x00' + struct.pack('<f', value)


def _coil(t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Voltage [V] and 8-bit current [A] of 24 V steps (20 ms on in every 50 ms)."""
    phase = np.mod(t, 0.05)
    on = phase < 0.02
    i = np.where(on, 24.0 / 13.0 * (1.0 - np.exp(-phase / 7e-3)),
                 24.0 / 13.0 * (1.0 - np.exp(-0.02 / 7e-3)) * np.exp(-(phase - 0.02) / 7e-3))
    i = np.clip(np.round((i + rng.normal(0.0, 3e-3, t.size)) / LSB_A), 0, 255) * LSB_A
    return np.where(on, 24.0, 0.0), i


def write_bag(path: Path, size_bytes: float) -> tuple[float, int]:
    """Write the bag; returns its duration [s] and its message count."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    image_type = 'sensor_msgs/msg/Image'
    img = store.types[image_type]
    hdr = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    pixels = np.random.default_rng(2).integers(0, 256, WIDTH * HEIGHT * 3, dtype=np.uint8)
    frame = bytes(store.serialize_cdr(img(
        header=hdr(stamp=stamp(sec=0, nanosec=0), frame_id='camera'), height=HEIGHT,
        width=WIDTH, encoding='rgb8', is_bigendian=0, step=WIDTH * 3, data=pixels),
        image_type))
    per_second = CAMERA_HZ * len(frame) + 2 * RATE_HZ * 8
    duration = max(1, int(round(size_bytes / per_second)))
    rng = np.random.default_rng(1)
    t0_ns = 1_764_000_000 * 10 ** 9
    count = 0
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cam = w.add_connection('/camera/image_raw', image_type, typestore=store)
        cur = w.add_connection('/coil/current', 'std_msgs/msg/Float32', typestore=store)
        vol = w.add_connection('/coil/voltage', 'std_msgs/msg/Float32', typestore=store)
        for second in range(duration):
            t = second + np.arange(RATE_HZ) / RATE_HZ
            v, i = _coil(t, rng)
            ns = t0_ns + np.round(t * 1e9).astype(np.int64)
            frames = iter(range(CAMERA_HZ))
            next_frame = next(frames)
            for k in range(RATE_HZ):
                if next_frame is not None and k * CAMERA_HZ >= next_frame * RATE_HZ:
                    w.write(cam, int(ns[k]) + 1, frame)
                    count += 1
                    next_frame = next(frames, None)
                w.write(vol, int(ns[k]), _float32(float(v[k])))
                w.write(cur, int(ns[k]), _float32(float(i[k])))
                count += 2
    return float(duration), count


def read_in_child(bag: Path) -> tuple[float, float, int, dict]:
    """Wall time [s], peak RSS [MB], exit status and the child's summary of one read."""
    env = {**os.environ, 'PYTHONPATH': str(HERE.parent / 'valve_model_pkg') + os.pathsep
           + os.environ.get('PYTHONPATH', '')}
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, '-c', _READ, str(bag), *MAP], env=env,
                            stdout=subprocess.PIPE, text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    elapsed = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    summary = json.loads(out.strip().splitlines()[-1]) if code == 0 and out.strip() else {}
    return elapsed, usage.ru_maxrss / 1024.0, code, summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--size-gb', type=float, default=2.0)
    parser.add_argument('--keep', type=Path, default=None,
                        help='write the bag here and keep it (default: a temporary folder)')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix='bench_import_bag_') as tmp:
        bag = (args.keep or Path(tmp)) / 'camera_and_coil'
        start = time.perf_counter()
        duration, count = write_bag(bag, args.size_gb * 1e9)
        size_gb = sum(f.stat().st_size for f in bag.iterdir()) / 1e9
        print(f'wrote {bag} ({size_gb:.2f} GB, {count} messages, {duration:.0f} s) in '
              f'{time.perf_counter() - start:.0f} s', file=sys.stderr)
        elapsed, peak_mb, code, summary = read_in_child(bag)
    load = load_text()
    print(f'read: exit {code}, {elapsed:.1f} s, peak {peak_mb:.0f} MB, {summary}; {load}',
          file=sys.stderr)
    lsb = summary.get('current_lsb_a')
    note = (f'{size_gb:.2f} GB MCAP bag, {count} messages over {duration:.0f} s: '
            f'{CAMERA_HZ} Hz 640x480 rgb8 images and 2 Float32 topics at {RATE_HZ} Hz; '
            f'--map {" --map ".join(MAP)}; {summary.get("samples", 0)} samples read '
            f'({summary.get("experiment", "-")} record), current step found '
            f'{"-" if not lsb else f"{1e3 * lsb:.3g} mA"}; exit {code}; {load}')
    what = f'read_measurements on a {args.size_gb:g} GB bag (mapped Float32 topics)'
    records = [
        record(f'{what}: time', elapsed, 's', None, None, 'reported', code == 0, note),
        record(f'{what}: peak memory', peak_mb, 'MB', 'memory target', MEMORY_TARGET_MB,
               '< 1024 MB', code == 0 and peak_mb < MEMORY_TARGET_MB, note)]
    path = write_results('import_bag', records)
    print(f'wrote {path}', file=sys.stderr)
    return 0 if all(r['passed'] for r in records) else 1


if __name__ == '__main__':
    sys.exit(main())
