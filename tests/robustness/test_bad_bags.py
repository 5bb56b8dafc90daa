"""Damaged bags: one line from the readers, and ``--recover`` keeps every intact chunk.

A bag with 64 flipped bytes in a chunk is refused by valve_identify and valve_report with
one line naming the bag (no traceback), and ``valve_recorder --recover`` keeps every
intact chunk before and after the damaged one.
"""
from __future__ import annotations

import random
import shutil
import struct
import subprocess
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from valve_model_pkg.recording import (BagWriter, McapScanner, build_typestore, recover_bag,
                                       reliable_qos)
from valve_model_pkg.recording.recovery import McapMessage
from valve_model_pkg.recording.synthetic import VALVE_STATE, valve_state_cdr

#: MCAP record header (MCAP specification): opcode uint8, record length uint64 LE.
_REC_HEAD = struct.Struct('<BQ')
N = 3000            # messages, 1 kHz
FLUSH_S = 0.5       # a chunk every 500 messages: 6 chunks


class _Clock:
    t = 0.0

    def __call__(self) -> float:
        return self.t


def write_bag(path: Path) -> Path:
    """A complete bag of ValveState messages in several chunks."""
    store = build_typestore()
    clock = _Clock()
    writer = BagWriter(path, store, flush_period_s=FLUSH_S, clock=clock).open()
    conn = writer.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
    for i, (t, raw) in enumerate(valve_state_cdr(store, N)):
        clock.t = i * 1e-3
        writer.write(conn, t, raw)
    writer.close()
    return path


def chunks(mcap: Path) -> list[tuple[int, int]]:
    """(offset, length) of every chunk record of an MCAP file."""
    data = mcap.read_bytes()
    pos, out = 8, []
    while pos + _REC_HEAD.size <= len(data):
        op, length = _REC_HEAD.unpack_from(data, pos)
        if op == 0x06:
            out.append((pos, length))
        if op == 0x02:
            break
        pos += _REC_HEAD.size + length
    return out


def damage(bag: Path, out: Path, chunk: int, n_bytes: int = 64, *,
           header_too: bool = False, seed: int = 11) -> tuple[Path, tuple[int, int]]:
    """A copy of ``bag`` with ``n_bytes`` random bytes flipped inside one chunk."""
    shutil.copytree(bag, out)
    (mcap,) = out.glob('*.mcap')
    offset, length = chunks(mcap)[chunk]
    data = bytearray(mcap.read_bytes())
    first = offset if header_too else offset + _REC_HEAD.size + 40
    for k in random.Random(seed).sample(range(first, offset + _REC_HEAD.size + length),
                                        n_bytes):
        data[k] ^= 0xFF
    mcap.write_bytes(bytes(data))
    return out, (offset, length)


@pytest.fixture(scope='module')
def good_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bag(tmp_path_factory.mktemp('bags') / 'good')


def _sequences(bag: Path) -> list[int]:
    store = build_typestore()
    with AnyReader([bag]) as reader:
        return [store.deserialize_cdr(raw, VALVE_STATE).sequence
                for _, _, raw in reader.messages()]


@pytest.mark.parametrize('header_too', [False, True])
def test_recover_keeps_every_intact_chunk_after_a_damaged_one(good_bag: Path, tmp_path: Path,
                                                              header_too: bool) -> None:
    (mcap,) = good_bag.glob('*.mcap')
    all_chunks = chunks(mcap)
    assert len(all_chunks) >= 5
    bad, _ = damage(good_bag, tmp_path / 'bad', 2, header_too=header_too)
    # which messages the damaged chunk held: those of the good file's chunk 2
    scanner = McapScanner(good_bag)
    store = build_typestore()
    chunk_of = {store.deserialize_cdr(rec.data, VALVE_STATE).sequence: scanner.report.chunks - 1
                for rec in scanner if isinstance(rec, McapMessage)}
    expected = [s for s in range(N) if chunk_of[s] != 2]
    lost = N - len(expected)
    assert 0 < lost < N // 3
    report = recover_bag(bad, tmp_path / 'fixed')
    assert report.messages == N - lost
    assert len(report.scan.skipped) == 1 and report.scan.skipped_bytes > 0
    assert 'skipped 1 damaged parts' in report.summary()
    seqs = _sequences(tmp_path / 'fixed')
    assert seqs == expected  # every message of every other chunk, in order


def test_valve_recorder_recover_reports_what_it_skipped(good_bag: Path,
                                                        tmp_path: Path) -> None:
    bad, (offset, _) = damage(good_bag, tmp_path / 'bad', 3)
    script = shutil.which('valve_recorder')
    assert script, 'source ros2_ws/env.bash'
    proc = subprocess.run([script, '--recover', str(bad), '-o', str(tmp_path / 'fixed')],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 'skipped 1 damaged parts' in proc.stdout
    assert f'at offset {offset}' in proc.stdout
    assert 'Traceback' not in proc.stderr
    assert len(_sequences(tmp_path / 'fixed')) == N - 500


@pytest.mark.parametrize('command', [
    ['valve_identify', '--fit', 'BAG', '-o', 'OUT/ident', '--quick', '--no-plots'],
    ['valve_report', 'BAG', '-o', 'OUT/report'],
])
@pytest.mark.parametrize('seed', [11, 12, 13])
def test_flipped_bytes_give_one_line_naming_the_bag(good_bag: Path, tmp_path: Path,
                                                    command: list[str], seed: int) -> None:
    bad, _ = damage(good_bag, tmp_path / 'bad', 2, seed=seed, header_too=seed == 13)
    script = shutil.which(command[0])
    assert script, 'source ros2_ws/env.bash'
    argv = [script] + [a.replace('BAG', str(bad)).replace('OUT', str(tmp_path))
                       for a in command[1:]]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr
    assert len(lines) == 1 and lines[0].startswith(f'{command[0]}: ') and str(bad) in lines[0]
