"""Killed bags: the scanner stops cleanly at any cut, recovery writes a complete bag."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosReliability

from suite_bags import FakeClock
from valve_model_pkg.recording import (BagFormatError, BagWriteError, BagWriter, McapScanner,
                                       recover_bag, reliable_qos)
from valve_model_pkg.recording.recovery import McapMessage
from valve_model_pkg.recording.synthetic import (DUTY_COMMAND, VALVE_STATE, duty_command_cdr,
                                                 valve_state_cdr)

N_STATE = 2500


def _killed_bag(tmp_path: Path, store, compression: str = 'none') -> tuple[Path, Path, int]:
    """A bag written with a 0.5 s flush period, copied before close (= SIGKILL), and the
    same bag closed normally; returns (killed, complete, flushed count)."""
    clock = FakeClock()
    w = BagWriter(tmp_path / 'complete', store, flush_period_s=0.5, clock=clock,
                  compression=compression).open()
    cs = w.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
    cc = w.add_topic('valve/duty_command', DUTY_COMMAND, [reliable_qos(50)])
    commands = iter(duty_command_cdr(store, [0.25] * 100, period_ns=100_000_000))
    for i, (t, raw) in enumerate(valve_state_cdr(store, N_STATE)):
        clock.t = i * 1e-3
        if i % 100 == 0:
            w.write(cc, *next(commands))
        w.write(cs, t, raw)
    flushed = w.flushed_count
    shutil.copytree(tmp_path / 'complete', tmp_path / 'killed')
    w.close()
    return tmp_path / 'killed', tmp_path / 'complete', flushed


def _state_sequences(reader: AnyReader) -> list[int]:
    conns = [c for c in reader.connections if c.topic == '/valve/state']
    return [reader.deserialize(raw, VALVE_STATE).sequence
            for _, _, raw in reader.messages(connections=conns)]


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_recovery_keeps_every_flushed_message_with_types_and_qos(tmp_path, store, compression):
    killed, _, flushed = _killed_bag(tmp_path, store, compression)
    assert not (killed / 'metadata.yaml').exists()
    report = recover_bag(killed)
    assert report.output == tmp_path / 'killed_recovered'
    assert report.messages == flushed
    assert report.counts['/valve/duty_command'] == 21  # written before the last flush (2.0 s)
    assert not report.scan.complete and 'without footer' in report.scan.stop_reason
    with AnyReader([report.output]) as reader:
        seqs = _state_sequences(reader)
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
    assert seqs == list(range(len(seqs)))  # continuous from the first message
    assert len(seqs) == flushed - 21
    assert qos['/valve/state'].reliability == QosReliability.RELIABLE
    assert qos['/valve/state'].depth == 1000


def test_any_cut_of_the_file_gives_a_prefix_of_whole_chunks(tmp_path, store) -> None:
    _, complete, _ = _killed_bag(tmp_path, store)
    data = (complete / 'complete.mcap').read_bytes()
    with AnyReader([complete]) as reader:
        all_raw = [bytes(raw) for _, _, raw in reader.messages()]
    chunk_ends = set()
    cut_dir = tmp_path / 'cut'
    cut_dir.mkdir()
    for cut in list(range(len(data), 40, -len(data) // 150)) + [len(data) - 1, 60]:
        (cut_dir / 'cut.mcap').write_bytes(data[:cut])
        scanner = McapScanner(cut_dir)
        got = [r.data for r in scanner if isinstance(r, McapMessage)]
        assert got == all_raw[:len(got)]
        assert scanner.report.valid_bytes <= cut
        chunk_ends.add(len(got))
    assert len(chunk_ends) >= 5  # several chunk boundaries were crossed
    assert len(all_raw) in chunk_ends


def test_a_zero_filled_tail_is_cut_off(tmp_path, store) -> None:
    killed, _, flushed = _killed_bag(tmp_path, store)
    (mcap,) = killed.glob('*.mcap')
    mcap.write_bytes(mcap.read_bytes() + b'\0' * 4096)
    scanner = McapScanner(killed)
    n = sum(isinstance(r, McapMessage) for r in scanner)
    assert n == flushed
    assert 'no valid record' in scanner.report.stop_reason
    assert scanner.report.discarded_bytes == 4096


def test_a_complete_bag_is_scanned_to_its_end(tmp_path, store) -> None:
    _, complete, _ = _killed_bag(tmp_path, store)
    scanner = McapScanner(complete / 'complete.mcap')
    n = sum(isinstance(r, McapMessage) for r in scanner)
    assert scanner.report.complete and scanner.report.stop_reason == ''
    assert n == N_STATE + 25
    report = recover_bag(complete, tmp_path / 'copy')
    assert report.messages == N_STATE + 25


def test_recovery_refuses_what_it_cannot_use(tmp_path, store) -> None:
    (tmp_path / 'junk').mkdir()
    (tmp_path / 'junk' / 'junk.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(BagFormatError, match='not an MCAP file'):
        recover_bag(tmp_path / 'junk')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagFormatError, match='no .mcap file'):
        recover_bag(tmp_path / 'empty')
    (tmp_path / 'magic').mkdir()
    (tmp_path / 'magic' / 'magic.mcap').write_bytes(b'\x89MCAP0\r\n')
    with pytest.raises(BagFormatError, match='nothing recoverable'):
        recover_bag(tmp_path / 'magic')
    killed, _, _ = _killed_bag(tmp_path, store)
    (tmp_path / 'taken').mkdir()
    with pytest.raises(BagWriteError, match='exists'):
        recover_bag(killed, tmp_path / 'taken')
