"""Any rosbag2 bag as ``ros2 bag record`` writes it: both storages, split, zstd file,
message and chunk compression, metadata versions 4..9, no metadata.yaml (reindexed in
memory), a user's own topics and types; bad bags refused in one line.

The bags are written with rosbags' writer (:func:`suite_bags.write_rosbag2`); what is read
back is compared with what was written. Small bags: each test takes milliseconds.
"""
from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from suite_bags import header, write_rosbag2
from valve_model_pkg.errors import BagFormatError, UnknownMessageTypeError
from valve_model_pkg.recording import (FieldSpec, bag_info, load_bag, load_bag_contents,
                                       read_fields, reindex_bag)
from valve_model_pkg.recording.reindex import storage_files

# lark (used by mcap-ros2-support to parse .msg) imports deprecated sre modules
pytestmark = pytest.mark.filterwarnings('ignore::DeprecationWarning:lark.utils')

N = 40                      # messages per topic
START_NS = 1_700_000_000_000_000_000
STEP_NS = 1_000_000         # 1 kHz
LATE_NS = 50_000            # telemetry received 50 us after its header stamp
#: A user's message types, in no typestore: the bag embeds their definitions.
COIL_MSG = 'float64 current\nfloat64 voltage\n'
TELEMETRY_MSG = 'std_msgs/Header header\nmy_drive/Coil coil\nfloat64 duty\nstring mode\n'


@pytest.fixture(scope='module')
def store():
    s = get_typestore(Stores.ROS2_JAZZY)
    s.register(get_types_from_msg(COIL_MSG, 'my_drive/msg/Coil'))
    s.register(get_types_from_msg(TELEMETRY_MSG, 'my_drive/msg/Telemetry'))
    return s


def _current(k: np.ndarray | int) -> np.ndarray | float:
    return 0.5 + 0.01 * k


def _messages(store) -> list[tuple[str, str, int, object]]:
    """A user's Float64 current (no header) and a telemetry type with a header and a
    nested field, interleaved in receive order."""
    types = store.types
    out = []
    for k in range(N):
        ns = START_NS + k * STEP_NS
        out.append(('/coil/current', 'std_msgs/msg/Float64', ns + 7,
                    types['std_msgs/msg/Float64'](data=_current(k))))
        out.append(('/drive/telemetry', 'my_drive/msg/Telemetry', ns + LATE_NS,
                    types['my_drive/msg/Telemetry'](
                        header=header(types, ns, 'coil'),
                        coil=types['my_drive/msg/Coil'](current=2 * _current(k), voltage=24.0),
                        duty=0.25 * (k % 4), mode='run')))
    return out


def _check_contents(bag: Path, data: dict) -> None:
    k = np.arange(N)
    cur = data['/coil/current']
    assert cur.msgtype == 'std_msgs/msg/Float64'
    np.testing.assert_array_equal(cur['data'], _current(k))
    np.testing.assert_array_equal(cur.log_time_ns, START_NS + k * STEP_NS + 7)
    tel = data['/drive/telemetry']
    np.testing.assert_array_equal(tel['coil.current'], 2 * _current(k))
    np.testing.assert_array_equal(tel['duty'], 0.25 * (k % 4))
    np.testing.assert_array_equal(tel.stamp_ns, START_NS + k * STEP_NS)
    np.testing.assert_array_equal(tel.log_time_ns, START_NS + k * STEP_NS + LATE_NS)
    assert list(tel['mode']) == ['run'] * N


LAYOUTS = [(storage, compression, split)
           for storage in ('mcap', 'sqlite3')
           for compression in ('none', 'file', 'message', 'chunk')
           for split in (1, 3)
           if not (storage == 'sqlite3' and compression == 'chunk')]


@pytest.mark.parametrize('metadata', [True, False], ids=['metadata', 'no-metadata'])
@pytest.mark.parametrize('storage, compression, split', LAYOUTS)
def test_every_layout_reads_back_what_was_written(tmp_path: Path, store, storage: str,
                                                  compression: str, split: int,
                                                  metadata: bool) -> None:
    bag = write_rosbag2(tmp_path / 'bag', store, _messages(store), storage=storage,
                        split=split, compression=compression, metadata=metadata)
    files = storage_files(bag)
    assert len(files) == split
    assert all(f.name.endswith('.zstd') == (compression == 'file') for f in files)
    contents = load_bag_contents(bag)
    _check_contents(bag, contents.topics)
    assert contents.available == {'/coil/current': 'std_msgs/msg/Float64',
                                  '/drive/telemetry': 'my_drive/msg/Telemetry'}
    if metadata:
        assert contents.notes == []
    else:
        assert 'reindexed in memory' in contents.notes[0]
        assert f'{split} {storage} file(s)' in contents.notes[0]
        if compression in ('file', 'message'):
            assert f'zstd {compression} compression' in contents.notes


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
@pytest.mark.parametrize('version', [4, 5, 6, 7, 8, 9])
def test_metadata_versions_4_to_9(tmp_path: Path, store, storage: str, version: int) -> None:
    bag = write_rosbag2(tmp_path / 'bag', store, _messages(store), storage=storage,
                        version=version)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == version
    assert ('files' in info) == (version >= 5)
    assert ('custom_data' in info) == (version >= 6)
    topic = info['topics_with_message_count'][0]['topic_metadata']
    assert ('type_description_hash' in topic) == (version >= 7)
    assert ('ros_distro' in info) == (version >= 8)
    assert isinstance(topic['offered_qos_profiles'], list if version >= 9 else str)
    _check_contents(bag, load_bag(bag))
    assert 'reliable' in bag_info(bag)


def test_a_bag_without_metadata_is_reindexed_in_memory_and_left_untouched(
        tmp_path: Path, store) -> None:
    whole = write_rosbag2(tmp_path / 'whole', store, _messages(store), split=3)
    written = yaml.safe_load((whole / 'metadata.yaml').read_text())
    written = written['rosbag2_bagfile_information']
    bag = tmp_path / 'bag'
    shutil.copytree(whole, bag)
    (bag / 'metadata.yaml').unlink()
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in bag.iterdir()}
    index = reindex_bag(bag)
    _check_contents(bag, load_bag(bag))
    info = bag_info(bag)
    after = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in bag.iterdir()}
    assert after == before                      # nothing written, nothing changed
    assert [f.name for f in index.files] == written['relative_file_paths']
    assert index.storage_identifier == written['storage_identifier'] and index.complete
    assert index.message_count == written['message_count']
    assert index.start_ns == written['starting_time']['nanoseconds_since_epoch']
    assert index.end_ns - index.start_ns == written['duration']['nanoseconds']
    assert {t: (i.msgtype, i.count) for t, i in index.topics.items()} == {
        t['topic_metadata']['name']: (t['topic_metadata']['type'], t['message_count'])
        for t in written['topics_with_message_count']}
    assert 'reindexed in memory' in info and f'Messages:          {2 * N}' in info


def test_split_files_are_read_in_index_order(tmp_path: Path) -> None:
    for name in ('run_10.mcap', 'run_2.mcap', 'run_1.mcap', 'notes.txt'):
        (tmp_path / name).write_bytes(b'')
    assert [p.name for p in storage_files(tmp_path)] == ['run_1.mcap', 'run_2.mcap',
                                                         'run_10.mcap']
    (tmp_path / 'run_3.db3').write_bytes(b'')
    with pytest.raises(BagFormatError, match='two storages'):
        storage_files(tmp_path)


def _drop_definitions(db3: Path) -> None:
    """A sqlite3 file as ros2 wrote it before Iron: no message_definitions table."""
    with sqlite3.connect(db3) as con:
        con.execute('DROP TABLE message_definitions')
        con.execute('UPDATE schema SET schema_version = 3')


def test_types_the_bag_does_not_embed_come_from_the_installed_definitions(
        tmp_path: Path, store) -> None:
    from valve_model_pkg.recording import build_typestore
    suite = build_typestore()
    cmd = suite.types['valve_msgs/msg/DutyCommand']
    msgs = [('/valve/duty_command', 'valve_msgs/msg/DutyCommand', START_NS + k * STEP_NS,
             cmd(header=header(suite.types, START_NS + k * STEP_NS), sequence=k,
                 duty=0.1 * k, pwm_frequency=50.0)) for k in range(N)]
    msgs += [('/coil/current', 'std_msgs/msg/Float64', START_NS + k,
              store.types['std_msgs/msg/Float64'](data=float(k))) for k in range(N)]
    bag = write_rosbag2(tmp_path / 'bag', suite, msgs, storage='sqlite3')
    _drop_definitions(next(bag.glob('*.db3')))
    data = load_bag(bag)
    np.testing.assert_allclose(data['/valve/duty_command']['duty'], 0.1 * np.arange(N))
    np.testing.assert_array_equal(data['/coil/current']['data'], np.arange(N))


def test_an_installed_definition_other_than_the_recorded_one_is_refused(
        tmp_path: Path) -> None:
    """valve_msgs/DutyCommand recorded with another definition, not embedded: the installed
    one has another type hash, so decoding with it would give wrong numbers."""
    other = get_typestore(Stores.ROS2_JAZZY)
    other.register(get_types_from_msg('float32 duty\n', 'valve_msgs/msg/DutyCommand'))
    msgs = [('/valve/duty_command', 'valve_msgs/msg/DutyCommand', START_NS + k,
             other.types['valve_msgs/msg/DutyCommand'](duty=0.5)) for k in range(N)]
    bag = write_rosbag2(tmp_path / 'bag', other, msgs, storage='sqlite3')
    _drop_definitions(next(bag.glob('*.db3')))
    with pytest.raises(BagFormatError, match='valve_msgs/msg/DutyCommand.*type hash') as info:
        load_bag(bag)
    assert str(bag) in str(info.value) and '\n' not in str(info.value)


def test_a_user_type_neither_embedded_nor_installed_is_named(tmp_path: Path, store) -> None:
    bag = write_rosbag2(tmp_path / 'bag', store, _messages(store), storage='sqlite3')
    _drop_definitions(next(bag.glob('*.db3')))
    with pytest.raises(UnknownMessageTypeError, match='my_drive/msg/Telemetry') as info:
        load_bag(bag, ['/drive/telemetry'])
    assert str(bag) in str(info.value)
    # the other topic's type is installed (std_msgs): it reads
    np.testing.assert_array_equal(load_bag(bag, ['/coil/current'])['/coil/current']['data'],
                                  _current(np.arange(N)))


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_user_fields_are_timed_by_header_stamps_where_the_type_has_them(
        tmp_path: Path, store, storage: str) -> None:
    bag = write_rosbag2(tmp_path / 'bag', store, _messages(store), storage=storage, split=3)
    rec = read_fields(bag, {'current': '/coil/current',
                            'current_2': '/drive/telemetry.coil.current',
                            'duty': FieldSpec('/drive/telemetry', 'duty')})
    k = np.arange(N)
    cur, cur2, duty = (rec.series[n] for n in ('current', 'current_2', 'duty'))
    np.testing.assert_array_equal(cur.values, _current(k))
    np.testing.assert_array_equal(cur.time_ns, START_NS + k * STEP_NS + 7)    # receive time
    np.testing.assert_array_equal(cur2.values, 2 * _current(k))
    np.testing.assert_array_equal(cur2.time_ns, START_NS + k * STEP_NS)       # header stamp
    np.testing.assert_array_equal(duty.values, 0.25 * (k % 4))
    assert (cur.time_source, cur2.time_source) == ('receive times', 'header stamps')
    notes = '\n'.join(rec.notes)
    assert 'current from /coil/current.data (std_msgs/msg/Float64, 40 messages), timed by ' \
        'the receive times (the type has no header)' in notes
    assert 'current_2 from /drive/telemetry.coil.current (my_drive/msg/Telemetry, 40 ' \
        'messages), timed by its header stamps' in notes


@pytest.mark.parametrize('text, spec', [
    ('/coil/current', FieldSpec('/coil/current', 'data')),
    ('coil/current', FieldSpec('/coil/current', 'data')),
    ('/valve/state.coil_current', FieldSpec('/valve/state', 'coil_current')),
    ('/drive/telemetry.coil.current', FieldSpec('/drive/telemetry', 'coil.current')),
    ('/joint_states.position[0]', FieldSpec('/joint_states', 'position', 0)),
])
def test_field_specs(text: str, spec: FieldSpec) -> None:
    assert FieldSpec.parse(text) == spec


@pytest.mark.parametrize('text', ['', '.data', '/a b', '/coil/current.', '/x.1bad',
                                  '/x.a[b]', '/x.a..b'])
def test_bad_field_specs_are_refused_naming_them(text: str) -> None:
    with pytest.raises(ValueError, match='expected TOPIC'):
        FieldSpec.parse(text)


def test_a_sequence_element_is_read_by_index(tmp_path: Path, store) -> None:
    js = store.types['sensor_msgs/msg/JointState']
    msgs = [('/js', 'sensor_msgs/msg/JointState', START_NS + k,
             js(header=header(store.types, START_NS + k), name=['a', 'b'],
                position=np.array([0.1 * k, 7.0]), velocity=np.array([], dtype=np.float64),
                effort=np.array([], dtype=np.float64))) for k in range(N)]
    bag = write_rosbag2(tmp_path / 'bag', store, msgs)
    rec = read_fields(bag, {'x': '/js.position[0]', 'y': '/js.position[1]'})
    np.testing.assert_allclose(rec.series['x'].values, 0.1 * np.arange(N))
    np.testing.assert_array_equal(rec.series['y'].values, 7.0)
    with pytest.raises(BagFormatError, match=r'holds 2 numbers per message'):
        read_fields(bag, {'x': '/js.position[2]'})


@pytest.fixture
def user_bag(tmp_path: Path, store) -> Path:
    return write_rosbag2(tmp_path / 'bag', store, _messages(store))


@pytest.mark.parametrize('spec, expected', [
    ('/coil/voltage', r'no topic /coil/voltage for the current; the bag has /coil/current '
                      r'\(std_msgs/msg/Float64\)'),
    ('/drive/telemetry.coil.curent', r"/drive/telemetry \(my_drive/msg/Telemetry\) has no "
                                     r"field 'coil.curent' for the current; its numeric "
                                     r'fields: coil.current, coil.voltage, duty'),
    ('/drive/telemetry.mode', r'/drive/telemetry.mode \(my_drive/msg/Telemetry, the current\) '
                              r'is text; expected a number per message'),
    ('/drive/telemetry.header.frame_id', r'is text; expected a number per message'),
])
def test_bad_fields_are_refused_in_one_line_naming_bag_topic_and_field(
        user_bag: Path, spec: str, expected: str) -> None:
    with pytest.raises(BagFormatError, match=expected) as info:
        read_fields(user_bag, {'current': spec})
    assert str(info.value).startswith(f'{user_bag}: ') and '\n' not in str(info.value)


def test_an_empty_topic_is_refused(tmp_path: Path, store) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    bag = tmp_path / 'bag'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        w.add_connection('/coil/current', 'std_msgs/msg/Float64', typestore=store)
    with pytest.raises(BagFormatError, match=r'topic /coil/current \(std_msgs/msg/Float64\) '
                                             r'has no messages; expected the current on it'):
        read_fields(bag, {'current': '/coil/current'})


def test_garbage_and_truncated_bags_are_refused_in_one_line(tmp_path: Path, store) -> None:
    garbage = tmp_path / 'garbage'
    garbage.mkdir()
    (garbage / 'garbage_0.mcap').write_bytes(b'not an mcap file at all' * 10)
    bag = write_rosbag2(tmp_path / 'bag', store, _messages(store))
    (mcap,) = bag.glob('*.mcap')
    mcap.write_bytes(mcap.read_bytes()[:mcap.stat().st_size // 2])
    db = write_rosbag2(tmp_path / 'db', store, _messages(store), storage='sqlite3')
    (db3,) = db.glob('*.db3')
    db3.write_bytes(b'SQLite format 3\x00' + b'\x00' * 100)
    for path, expected in [(garbage, 'not an MCAP file'),
                           (tmp_path / 'garbage' / 'garbage_0.mcap', 'not an MCAP file'),
                           (bag, 'cannot be read as a rosbag2 bag'),
                           (db, 'cannot be read as a rosbag2 bag'),
                           (tmp_path / 'nothing', 'does not exist')]:
        with pytest.raises(BagFormatError, match=expected) as info:
            read_fields(path, {'current': '/coil/current'})
        assert str(path) in str(info.value) and '\n' not in str(info.value)


@pytest.mark.parametrize('compression, split', [('none', 3), ('chunk', 1)])
def test_written_mcap_files_are_valid_for_the_independent_reader(
        tmp_path: Path, store, compression: str, split: int) -> None:
    """Each storage file of a (split) bag is a complete MCAP file whose every message the
    MCAP project's reader and ROS 2 decoder decode: the test bags are valid bags."""
    make_reader = pytest.importorskip('mcap.reader').make_reader
    decoder = pytest.importorskip('mcap_ros2.decoder').DecoderFactory
    bag = write_rosbag2(tmp_path / 'bag', store, _messages(store), split=split,
                        compression=compression)
    current, coil = [], []
    for path in storage_files(bag):
        with path.open('rb') as f:
            for _, channel, _, msg in make_reader(
                    f, decoder_factories=[decoder()]).iter_decoded_messages():
                if channel.topic == '/coil/current':
                    current.append(msg.data)
                else:
                    coil.append(msg.coil.current)
    np.testing.assert_array_equal(current, _current(np.arange(N)))
    np.testing.assert_array_equal(coil, 2 * _current(np.arange(N)))
