"""Suite bags as rosbag2 writes them, read by an independent MCAP reader and decoder.

The reader is the MCAP project's own (``mcap``) with its ROS 2 decoder
(``mcap-ros2-support``): nothing of rosbags or of the suite is involved in reading.
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
import yaml

from valve_model_pkg.recording import (BagWriter, QueuedBagWriter,
                                       recover_bag, reliable_qos)
from valve_model_pkg.recording.synthetic import (DUTY_COMMAND, VALVE_STATE, duty_command_cdr,
                                                 valve_state_cdr)

# lark (used by mcap-ros2-support to parse .msg) imports deprecated sre modules
pytestmark = pytest.mark.filterwarnings('ignore::DeprecationWarning:lark.utils')


def _mcap():
    """The MCAP reader and ROS 2 decoder, imported inside a test (under its warning filter).
    """
    return (pytest.importorskip('mcap.reader').make_reader,
            pytest.importorskip('mcap_ros2.decoder').DecoderFactory)


def _write(path: Path, store, *, compression: str = 'none', queued: bool = False
           ) -> tuple[dict[str, int], list[float]]:
    """A suite bag: 1 kHz ValveState and 10 duty commands; returns counts and duties."""
    states = valve_state_cdr(store, 2500)
    duties = [0.1 * i for i in range(10)]
    commands = duty_command_cdr(store, duties, period_ns=250_000_000)
    writer = BagWriter(path, store, compression=compression, flush_period_s=0.2)
    if queued:
        qw = QueuedBagWriter(writer).start()
        ks = qw.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
        kc = qw.add_topic('valve/duty_command', DUTY_COMMAND, [reliable_qos(50)])
        for t, raw in commands:
            qw.put(kc, t, raw)
        for t, raw in states:
            qw.put(ks, t, raw)
        qw.close()
    else:
        with writer as w:
            cs = w.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
            cc = w.add_topic('/valve/duty_command', DUTY_COMMAND, [reliable_qos(50)])
            for t, raw in commands:
                w.write(cc, t, raw)
            for t, raw in states:
                w.write(cs, t, raw)
    return {'/valve/state': len(states), '/valve/duty_command': len(commands)}, duties


def read_with_mcap(bag: Path) -> tuple[Counter, dict, list, dict]:
    """Decode every message of the bag's MCAP file with the MCAP library alone.

    Returns the message count per topic, each channel's metadata by topic, the decoded
    duty commands and the file's metadata records.
    """
    (mcap_file,) = bag.glob('*.mcap')
    counts: Counter = Counter()
    channels: dict[str, dict[str, str]] = {}
    duties: list[float] = []
    make_reader, decoder_factory = _mcap()
    with open(mcap_file, 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[decoder_factory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            channels[channel.topic] = dict(channel.metadata)
            assert schema.encoding == 'ros2msg' and channel.message_encoding == 'cdr'
            if channel.topic == '/valve/state':
                assert decoded.sequence == counts[channel.topic] - 1
                assert decoded.header.frame_id is not None
            else:
                duties.append(decoded.duty)
        summary = reader.get_summary()
        records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    # the summary's own statistics agree with what was decoded
    by_id = {c.id: c.topic for c in summary.channels.values()}
    assert {by_id[i]: n for i, n in summary.statistics.channel_message_counts.items()} \
        == dict(counts)
    return counts, channels, duties, records


@pytest.mark.parametrize('compression, queued', [('none', False), ('zstd', False),
                                                 ('none', True)])
def test_mcap_reader_decodes_and_counts_every_message(tmp_path, store, compression,
                                                      queued) -> None:
    bag = tmp_path / 'bag'
    written, duties = _write(bag, store, compression=compression, queued=queued)
    counts, channels, decoded_duties, _ = read_with_mcap(bag)
    assert dict(counts) == written
    assert decoded_duties == pytest.approx(duties)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['ros_distro'] == 'jazzy'
    in_yaml = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    for topic, meta in channels.items():
        # the two keys rosbag2's MCAP storage writes into every channel
        assert set(meta) == {'offered_qos_profiles', 'topic_type_hash'}, meta
        assert meta['topic_type_hash'].startswith('RIHS01_')
        assert meta['topic_type_hash'] == \
            in_yaml[topic]['topic_metadata']['type_description_hash']
        msgtype = in_yaml[topic]['topic_metadata']['type']
        assert meta['topic_type_hash'] == store.hash_rihs01(msgtype)
        assert 'reliability: reliable' in meta['offered_qos_profiles']
        assert in_yaml[topic]['message_count'] == written[topic]


def test_the_mcap_file_says_jazzy_too(tmp_path, store) -> None:
    """rosbag2 also embeds its metadata in the MCAP file (record ``rosbag2``)."""
    bag = tmp_path / 'bag'
    _write(bag, store)
    *_, records = read_with_mcap(bag)
    embedded = yaml.safe_load(records['rosbag2']['serialized_metadata'])
    assert embedded['ros_distro'] == 'jazzy'
    assert 'rosbags' not in records['rosbag2']['serialized_metadata'].split('ros_distro')[1]


def test_a_recovered_bag_is_written_the_same_way(tmp_path, store) -> None:
    bag = tmp_path / 'bag'
    written, _ = _write(bag, store)
    (bag / 'metadata.yaml').unlink()  # as after SIGKILL (the file itself is complete here)
    recover_bag(bag, tmp_path / 'fixed')
    counts, channels, _, _ = read_with_mcap(tmp_path / 'fixed')
    assert dict(counts) == written
    assert all(m['topic_type_hash'].startswith('RIHS01_') for m in channels.values())
    info = yaml.safe_load((tmp_path / 'fixed' / 'metadata.yaml').read_text())
    assert info['rosbag2_bagfile_information']['ros_distro'] == 'jazzy'
