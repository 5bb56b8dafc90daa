"""load_bag: numpy arrays per topic and field, from complete and from killed bags."""
from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest

from valve_model_pkg.recording import arrays as arrays_module
from valve_model_pkg.recording import (BagFormatError, BagWriter, PublisherSequenceGaps,
                                       bag_info, load_bag, reliable_qos, sequence_gaps)
from valve_model_pkg.recording.synthetic import (DUTY_COMMAND, VALVE_STATE, duty_command_cdr,
                                                 valve_state_cdr)

START_NS = 1_700_000_000_000_000_000


@pytest.fixture
def suite_bag(tmp_path, store):
    """ValveState at 1 kHz with one lost message, commands, joint states, diagnostics."""
    states = valve_state_cdr(store, 1000, start_ns=START_NS)
    del states[500]  # a gap: sequence 500 missing
    commands = duty_command_cdr(store, [0.2, 0.4, 0.6], start_ns=START_NS)
    js = store.types['sensor_msgs/msg/JointState']
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    diag = store.types['diagnostic_msgs/msg/DiagnosticArray']
    status = store.types['diagnostic_msgs/msg/DiagnosticStatus']
    kv = store.types['diagnostic_msgs/msg/KeyValue']
    with BagWriter(tmp_path / 'bag', store, flush_period_s=0.0) as w:
        cs = w.add_topic('valve/state', VALVE_STATE, [reliable_qos(1000)])
        cc = w.add_topic('valve/duty_command', DUTY_COMMAND)
        cj = w.add_topic('cylinder/joint_states', 'sensor_msgs/msg/JointState')
        cr = w.add_topic('ragged', 'sensor_msgs/msg/JointState')
        cd = w.add_topic('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')
        for t, raw in commands:
            w.write(cc, t, raw)
        for t, raw in states:
            w.write(cs, t, raw)
        for i in range(5):
            msg = js(header=header(stamp=stamp(sec=1, nanosec=i), frame_id=''),
                     name=['piston'], position=np.array([0.01 * i]),
                     velocity=np.array([0.1]), effort=np.array([], dtype=np.float64))
            w.write(cj, START_NS + i, bytes(store.serialize_cdr(msg, msg.__msgtype__)))
            rag = js(header=header(stamp=stamp(sec=1, nanosec=i), frame_id=''),
                     name=['a'] * i, position=np.arange(i, dtype=np.float64),
                     velocity=np.array([], dtype=np.float64),
                     effort=np.array([], dtype=np.float64))
            w.write(cr, START_NS + i, bytes(store.serialize_cdr(rag, rag.__msgtype__)))
        d = diag(header=header(stamp=stamp(sec=2, nanosec=0), frame_id=''),
                 status=[status(level=1, name='sim', message='late', hardware_id='v',
                                values=[kv(key='ticks', value='7')])])
        w.write(cd, START_NS + 5, bytes(store.serialize_cdr(d, d.__msgtype__)))
    return tmp_path / 'bag'


def test_valve_state_fields_come_as_typed_arrays(suite_bag) -> None:
    data = load_bag(suite_bag)
    assert set(data) == {'/valve/state', '/valve/duty_command', '/cylinder/joint_states',
                         '/ragged', '/diagnostics'}
    s = data['/valve/state']
    assert len(s) == 999 and s.msgtype == VALVE_STATE
    assert s['sequence'].dtype == np.uint64
    assert s['coil_current'].dtype == np.float64 and s['coil_current'].shape == (999,)
    assert s['position_measured'].dtype == np.bool_
    assert s['source'].dtype == np.uint8
    assert list(np.unique(s['header.frame_id'])) == ['valve']
    np.testing.assert_array_equal(s.log_time_ns, s.stamp_ns)  # written with stamp = time
    np.testing.assert_array_equal(np.diff(s.stamp_ns)[:499], 1_000_000)
    np.testing.assert_allclose(s.t_s[:500], 1e-3 * np.arange(500), rtol=0, atol=1e-12)
    assert s.t_s[500] == pytest.approx(0.501, abs=1e-12)  # after the gap
    assert sequence_gaps(s['sequence']) == (1, 1)
    with pytest.raises(KeyError, match='no field .nope.*coil_current'):
        s['nope']
    np.testing.assert_allclose(data['/valve/duty_command']['duty'], [0.2, 0.4, 0.6])


def test_sequences_and_nested_messages(suite_bag) -> None:
    data = load_bag(suite_bag, topics=['cylinder/joint_states', '/ragged', 'diagnostics'])
    assert set(data) == {'/cylinder/joint_states', '/ragged', '/diagnostics'}
    js = data['/cylinder/joint_states']
    assert js['position'].shape == (5, 1)  # fixed length: a 2-D array
    np.testing.assert_allclose(js['position'][:, 0], 0.01 * np.arange(5))
    assert js['effort'].shape == (5, 0)
    assert js['name'][0] == ['piston']
    rag = data['/ragged']['position']  # ragged: an object array of 1-D arrays
    assert rag.dtype == object and [len(r) for r in rag] == [0, 1, 2, 3, 4]
    status = data['/diagnostics']['status'][0]
    assert status[0].message == 'late' and status[0].values[0].value == '7'


@pytest.mark.parametrize('block', [1, 2, 3])
def test_long_bags_are_converted_in_blocks_with_the_same_result(suite_bag, monkeypatch, block):
    whole = load_bag(suite_bag)
    monkeypatch.setattr(arrays_module, 'BLOCK_MESSAGES', block)
    blocked = load_bag(suite_bag)
    for topic, data in whole.items():
        np.testing.assert_array_equal(blocked[topic].log_time_ns, data.log_time_ns)
        for name, arr in data.fields.items():
            got = blocked[topic][name]
            if arr.dtype == object or got.dtype == object:  # ragged rows, message lists
                assert len(got) == len(arr)
                for a, b in zip(got, arr):  # message objects compare by identity
                    assert repr(list(a)) == repr(list(b)), (topic, name)
            else:
                np.testing.assert_array_equal(got, arr, err_msg=f'{topic} {name}')


@pytest.mark.parametrize('sequence, expected', [
    ([], (0, 0)),
    ([5], (0, 0)),
    ([0, 1, 2, 3], (0, 0)),
    ([0, 2, 3, 7], (2, 4)),
    ([10, 11, 0, 1], (0, 0)),  # a restarted publisher is not a loss
    ([3, 3, 4], (0, 0)),
])
def test_sequence_gaps(sequence, expected) -> None:
    assert sequence_gaps(np.array(sequence, dtype=np.uint64)) == expected


@pytest.mark.parametrize('messages, lost', [
    # (publication sequence number, writers matched at its arrival)
    ([(1, 1), (2, 1), (5, 1), (6, 1)], 2),
    ([(None, 1), (4, 1), (6, 1)], 1),  # a middleware without numbers counts from the first
    # two writers interleave their own numbering: nothing is lost
    ([(1, 1), (40, 2), (2, 2), (41, 2), (3, 2)], 0),
    # the second writer has left; the first's numbers go on from where it was, so its
    # next message is compared with its own, not with the writer that left
    ([(1, 1), (40, 2), (2, 2), (41, 2), (3, 1), (4, 1), (6, 1)], 1),
    ([(10, 1), (0, 1), (1, 1)], 0),  # a restarted writer is not a loss
    ([(1, 1), (2, 0), (3, 1)], 0),  # no writer matched: the count cannot be trusted
])
def test_publisher_sequence_gaps_count_only_one_writer(messages, lost) -> None:
    gaps = PublisherSequenceGaps()
    for seq, matched in messages:
        gaps.observe(seq, matched)
    assert gaps.lost == lost


def test_killed_bag_is_read_up_to_its_last_chunk(tmp_path, store, caplog) -> None:
    w = BagWriter(tmp_path / 'bag', store, flush_period_s=0.0).open()
    conn = w.add_topic('valve/state', VALVE_STATE)
    for t, raw in valve_state_cdr(store, 700):
        w.write(conn, t, raw)
    w.flush()
    for t, raw in valve_state_cdr(store, 300, first_sequence=700):
        w.write(conn, t, raw)
    shutil.copytree(tmp_path / 'bag', tmp_path / 'killed')
    w.close()
    with caplog.at_level(logging.WARNING):
        data = load_bag(tmp_path / 'killed')
    assert 'incomplete' in caplog.text
    np.testing.assert_array_equal(data['/valve/state']['sequence'], np.arange(700))
    with pytest.raises(BagFormatError, match='--recover'):
        load_bag(tmp_path / 'killed', allow_incomplete=False)
    assert len(load_bag(tmp_path / 'bag')['/valve/state']) == 1000
    info = bag_info(tmp_path / 'killed')
    assert 'INCOMPLETE' in info and 'Count: 700' in info and '--recover' in info


def test_bag_info_reads_like_ros2_bag_info(suite_bag) -> None:
    info = bag_info(suite_bag)
    assert 'Storage id:        mcap' in info
    assert 'Messages:          1013' in info
    assert ('Topic: /valve/state | Type: valve_msgs/msg/ValveState | Count: 999 | '
            'Serialization Format: cdr | QoS: reliable/volatile') in info


def test_not_a_bag_is_refused(tmp_path) -> None:
    with pytest.raises(BagFormatError, match='does not exist'):
        load_bag(tmp_path / 'nothing')
    (tmp_path / 'bad').mkdir()
    (tmp_path / 'bad' / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    with pytest.raises(BagFormatError, match='cannot be read'):
        load_bag(tmp_path / 'bad')
