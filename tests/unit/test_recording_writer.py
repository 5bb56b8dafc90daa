"""BagWriter / QueuedBagWriter: bags that rosbags, ros2 bag and Foxglove read; flush policy."""
from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinitionFormat, QosReliability
from rosbags.rosbag2.storage_mcap import McapWriter

from suite_bags import FakeClock
from valve_model_pkg.recording import (BagWriteError, BagWriter, McapScanner, QueuedBagWriter,
                                       UnknownMessageTypeError, reliable_qos)
from valve_model_pkg.recording.recovery import McapChannel, McapMessage, McapSchema
from valve_model_pkg.recording.synthetic import (DUTY_COMMAND, VALVE_STATE, duty_command_cdr,
                                                 valve_state_cdr)


def _write_suite_bag(path: Path, store, n_state: int = 3000, **kwargs) -> tuple[list, list]:
    states = valve_state_cdr(store, n_state)
    commands = duty_command_cdr(store, [0.1 * i for i in range(10)], period_ns=300_000_000)
    with BagWriter(path, store, **kwargs) as w:
        cs = w.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
        cc = w.add_topic('/valve/duty_command', DUTY_COMMAND, [reliable_qos(50)])
        ci = iter(commands)
        nxt = next(ci, None)
        for t, raw in states:
            while nxt is not None and nxt[0] <= t:
                w.write(cc, *nxt)
                nxt = next(ci, None)
            w.write(cs, t, raw)
    return states, commands


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_anyreader_reads_everything_back_with_embedded_types(tmp_path, store, compression):
    states, commands = _write_suite_bag(tmp_path / 'bag', store, compression=compression)
    with AnyReader([tmp_path / 'bag']) as reader:  # no default typestore: embedded only
        conns = {c.topic: c for c in reader.connections}
        assert set(conns) == {'/valve/state', '/valve/duty_command'}
        for c in conns.values():
            assert c.msgdef.format == MessageDefinitionFormat.MSG
            assert c.digest.startswith('RIHS01_')
        got = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
        seqs = [reader.deserialize(raw, VALVE_STATE).sequence
                for topic, _, raw in got if topic == '/valve/state']
        duties = [reader.deserialize(raw, DUTY_COMMAND).duty
                  for topic, _, raw in got if topic == '/valve/duty_command']
    assert [r for topic, _, r in got if topic == '/valve/state'] == [r for _, r in states]
    assert seqs == list(range(len(states)))
    assert duties == pytest.approx([0.1 * i for i in range(10)])
    assert conns['/valve/state'].msgcount == len(states)


def test_metadata_is_what_jazzy_rosbag2_writes(tmp_path, store) -> None:
    _write_suite_bag(tmp_path / 'bag', store, custom_data={'recorder': 'test'})
    info = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['bag.mcap']
    assert info['custom_data'] == {'recorder': 'test'}
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    state = topics['/valve/state']
    assert state['message_count'] == 3000
    assert state['topic_metadata']['type'] == VALVE_STATE
    assert state['topic_metadata']['serialization_format'] == 'cdr'
    qos = state['topic_metadata']['offered_qos_profiles']
    assert qos[0]['reliability'] == 'reliable' and qos[0]['durability'] == 'volatile'
    assert qos[0]['history'] == 'keep_last' and qos[0]['depth'] == 1000


def test_mcap_has_ros2_profile_schemas_and_channel_qos(tmp_path, store) -> None:
    """What Foxglove, PlotJuggler and rosbag2's MCAP plugin need from the file itself."""
    _write_suite_bag(tmp_path / 'bag', store)
    scanner = McapScanner(tmp_path / 'bag')
    records = list(scanner)
    assert scanner.report.complete and scanner.report.profile == 'ros2'
    schemas = {r.name: r for r in records if isinstance(r, McapSchema)}
    assert schemas[VALVE_STATE].encoding == 'ros2msg'
    assert 'float64 coil_current' in schemas[VALVE_STATE].data
    assert 'MSG: builtin_interfaces/Time' in schemas[VALVE_STATE].data
    channels = {r.topic: r for r in records if isinstance(r, McapChannel)}
    assert channels['/valve/state'].message_encoding == 'cdr'
    assert 'reliability: reliable' in channels['/valve/state'].metadata['offered_qos_profiles']


def test_identification_reader_reads_a_recorded_bag(tmp_path, store) -> None:
    from valve_model_pkg.identification.bag_reader import read_bag
    states, _ = _write_suite_bag(tmp_path / 'bag', store)
    m = read_bag(tmp_path / 'bag')
    assert m.n_samples == len(states)
    assert m.n_gaps == 0
    # read_bag forms epoch seconds in float64 (0.24 us resolution), hence the tolerance
    assert m.sample_rate_hz == pytest.approx(1000.0, rel=1e-3)


def test_flush_puts_completed_chunks_on_disk_within_the_period(tmp_path, store) -> None:
    """A copy of the file taken while writing (a killed writer) holds the flushed ones."""
    clock = FakeClock()
    w = BagWriter(tmp_path / 'bag', store, flush_period_s=0.5, clock=clock).open()
    conn = w.add_topic('valve/state', VALVE_STATE)
    states = valve_state_cdr(store, 1800)
    for i, (t, raw) in enumerate(states):
        clock.t = i * 1e-3
        w.write(conn, t, raw)
    assert w.flush_count == 3  # at 0.5, 1.0, 1.5 s
    assert w.flushed_count == 1501
    snapshot = tmp_path / 'killed'
    shutil.copytree(tmp_path / 'bag', snapshot)
    w.close()
    assert not (snapshot / 'metadata.yaml').exists()
    msgs = [r for r in McapScanner(snapshot) if isinstance(r, McapMessage)]
    assert [m.data for m in msgs] == [raw for _, raw in states[:1501]]


def test_without_a_period_nothing_is_flushed_before_a_full_chunk(tmp_path, store) -> None:
    clock = FakeClock()
    w = BagWriter(tmp_path / 'bag', store, flush_period_s=0.0, clock=clock).open()
    conn = w.add_topic('valve/state', VALVE_STATE)
    for i, (t, raw) in enumerate(valve_state_cdr(store, 2000)):
        clock.t = i * 1e-3
        w.write(conn, t, raw)
    w.flush_if_due()
    assert w.flushed_count == 0
    w.close()
    assert w.flushed_count == 2000


def test_an_existing_bag_is_never_overwritten(tmp_path, store) -> None:
    (tmp_path / 'bag').mkdir()
    with pytest.raises(BagWriteError, match='exists'):
        BagWriter(tmp_path / 'bag', store).open()


def test_topic_type_conflicts_and_unknown_types_are_refused(tmp_path, store) -> None:
    with BagWriter(tmp_path / 'bag', store) as w:
        first = w.add_topic('valve/state', VALVE_STATE)
        assert w.add_topic('/valve/state', VALVE_STATE) is first
        with pytest.raises(BagWriteError, match='added as valve_msgs/msg/ValveState'):
            w.add_topic('valve/state', DUTY_COMMAND)
        with pytest.raises(UnknownMessageTypeError, match='nope/msg/Nope'):
            w.add_topic('x', 'nope/msg/Nope')


@pytest.mark.parametrize('kwargs, match', [
    ({'flush_period_s': -1.0}, 'flush_period_s'),
    ({'compression': 'lz4'}, 'compression'),
])
def test_bad_settings_are_refused(tmp_path, store, kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        BagWriter(tmp_path / 'bag', store, **kwargs)


def test_rosbags_internals_the_flush_relies_on_are_there() -> None:
    """rosbags is pinned; this fails loudly if an upgrade moves what flush() uses."""
    assert callable(McapWriter.close_chunk)
    src = McapWriter.__init__.__code__.co_names
    assert 'chunk' in src and 'bio' in src


def test_queued_writer_takes_messages_from_many_threads(tmp_path, store) -> None:
    states = valve_state_cdr(store, 4000)
    commands = duty_command_cdr(store, [0.5] * 400, period_ns=1_000_000)
    qw = QueuedBagWriter(BagWriter(tmp_path / 'bag', store, flush_period_s=0.05)).start()
    ks = qw.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
    kc = qw.add_topic('valve/duty_command', DUTY_COMMAND)
    assert qw.add_topic('/valve/state', VALVE_STATE) == ks

    def produce(key, items):
        for t, raw in items:
            qw.put(key, t, raw)

    threads = [threading.Thread(target=produce, args=(ks, states)),
               threading.Thread(target=produce, args=(kc, commands))]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    stats = qw.close()
    assert stats.received == stats.written == stats.flushed == 4400
    assert stats.error == '' and stats.queued == 0
    with AnyReader([tmp_path / 'bag']) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    assert counts == {'/valve/state': 4000, '/valve/duty_command': 400}
    assert qos['/valve/state'][0].reliability == QosReliability.RELIABLE


def _poll(condition, timeout_s: float = 10.0) -> None:
    """Return once ``condition()`` holds or ``timeout_s`` has passed (the caller asserts)."""
    deadline = time.monotonic() + timeout_s
    tick = threading.Event()
    while not condition() and time.monotonic() < deadline:
        tick.wait(0.005)


def test_queued_writer_flushes_when_messages_stop(tmp_path, store) -> None:
    qw = QueuedBagWriter(BagWriter(tmp_path / 'bag', store, flush_period_s=0.05,
                                   fsync=False)).start()
    key = qw.add_topic('valve/state', VALVE_STATE)
    for t, raw in valve_state_cdr(store, 50):
        qw.put(key, t, raw)
    _poll(lambda: qw.stats().flushed >= 50)  # the thread flushes on its own, no close
    assert qw.stats().flushed == 50
    qw.close()


def test_a_failing_writer_thread_is_reported_not_swallowed(tmp_path, store) -> None:
    qw = QueuedBagWriter(BagWriter(tmp_path / 'bag', store)).start()
    qw.put(99, 0, b'not a known topic key')
    with pytest.raises(BagWriteError, match='bag writer failed'):
        qw.close()  # joins the writer thread, which stopped on the unknown key
    assert isinstance(qw.error, KeyError)
    with pytest.raises(BagWriteError, match='bag writer stopped'):
        qw.put(1, 0, b'')
