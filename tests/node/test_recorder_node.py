"""valve_recorder as its own process: no loss at 1 kHz, SIGINT/SIGTERM close, SIGKILL recovery."""
from __future__ import annotations

import signal
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinitionFormat, QosReliability

from valve_model_pkg.nodes import common
from valve_model_pkg.nodes.probe import StateProbe
from valve_model_pkg.recording import SUITE_TOPICS, load_bag, sequence_gaps

from node_harness import Diagnostics, DutyCommander, NodeProcess, poll_until

pytestmark = pytest.mark.node

STATE = '/valve/state'
DUTY = '/valve/duty_command'
RECORDER_STATUS = 'valve_recorder: bag writer'


def _start_recorder(start_node, bag: Path, *params: str):
    args = []
    for p in ('flush_period_s:=0.5', 'diagnostics_period_s:=0.2') + params:
        args += ['-p', p]
    return start_node('valve_recorder', '-o', str(bag), '--ros-args', *args)


@dataclass(frozen=True)
class Recording:
    """A simulator at 1 kHz and a recorder, seen from the test process."""

    sim: NodeProcess
    rec: NodeProcess
    probe: StateProbe
    commands: DutyCommander
    diag: Diagnostics


def _start_and_match(start_node, ros, bag: Path, *params: str) -> Recording:
    """valve_simulator at 1 kHz and the recorder, both matched with the test's publisher."""
    sim = start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=1000.0')
    rec = _start_recorder(start_node, bag, *params)
    probe = ros.add(StateProbe('test_probe'))
    commands = DutyCommander(probe)
    diag = Diagnostics(probe, RECORDER_STATUS)
    ros.wait_for(lambda: probe.count > 10, 30.0, 'valve/state from the simulator')
    ros.wait_for(lambda: diag.int(f'count {STATE}', 0) > 10, 30.0,
                 f'the recorder receiving valve/state\n{rec.output[-2000:]}')
    # the command publisher matched with the simulator and the recorder (DDS-level count)
    ros.wait_matched([commands.publisher], 'simulator and recorder', count=2, timeout_s=30.0)
    # the recorder says what its subscriptions matched: the simulator's state writer, and
    # every command writer the graph lists
    ros.wait_for(lambda: diag.int(f'matched {STATE}', 0) == 1
                 and diag.int(f'matched {DUTY}', 0) == probe.count_publishers(DUTY) >= 1,
                 30.0,
                 f'the recorder reporting its matched publishers: {diag.values}')
    return Recording(sim, rec, probe, commands, diag)


@dataclass(frozen=True)
class BagContents:
    """valve/state sequence numbers and stamps [ns], duty commands, connections by topic."""

    seq: np.ndarray
    stamps: np.ndarray
    duties: list[float]
    conns: dict


def _state_and_duties(bag: Path) -> BagContents:
    with AnyReader([bag]) as reader:  # types from the definitions embedded in the bag only
        conns = {c.topic: c for c in reader.connections}
        seq, stamps, duties = [], [], []
        wanted = [conns[t] for t in (STATE, DUTY) if t in conns]
        for conn, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == STATE:
                seq.append(msg.sequence)
                stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            else:
                duties.append(msg.duty)
    return BagContents(np.array(seq), np.array(stamps, dtype=np.int64), duties, conns)


def test_suite_topic_table_matches_the_nodes_contract() -> None:
    contract = {
        common.TOPIC_STATE: 'valve_msgs/msg/ValveState',
        common.TOPIC_DUTY_COMMAND: 'valve_msgs/msg/DutyCommand',
        common.TOPIC_FLOW_COMMAND: 'valve_msgs/msg/FlowCommand',
        common.TOPIC_SUPPLY_PRESSURE: 'sensor_msgs/msg/FluidPressure',
        common.TOPIC_OUTPUT_PRESSURE: 'sensor_msgs/msg/FluidPressure',
        common.TOPIC_FLOW_STATUS: 'valve_msgs/msg/FlowToDutyStatus',
        common.TOPIC_DIAGNOSTICS: 'diagnostic_msgs/msg/DiagnosticArray',
    }
    for topic, msgtype in contract.items():
        assert SUITE_TOPICS[topic] == msgtype, topic


@pytest.mark.serial   # keeps up with 1 kHz in wall time, no message lost
def test_records_1khz_state_and_every_command_without_loss(start_node, ros, tmp_path):
    bag = tmp_path / 'bag'
    run = _start_and_match(start_node, ros, bag)
    rec = run.rec
    for i in range(30):  # 3 s of 10 Hz duty commands while the state runs at 1 kHz
        run.commands.send(round(0.1 + 0.02 * i, 3))
        ros.spin_for(0.1)
    sent = run.commands.sent
    # every command reached the recorder before it is stopped (its own count)
    ros.wait_for(lambda: run.diag.int(f'count {DUTY}', 0) >= len(sent), 30.0,
                 f'the recorder counting {len(sent)} duty commands ({run.diag.values})')
    assert rec.stop() == 0, rec.output[-3000:]
    assert run.sim.alive()

    assert (bag / 'metadata.yaml').is_file()
    got = _state_and_duties(bag)
    seq, stamps, duties, conns = got.seq, got.stamps, got.duties, got.conns
    # every state message from the first recorded to the last, none lost
    assert len(seq) > 2500, rec.output[-2000:]
    assert np.all(np.diff(seq) == 1), f'sequence gaps: {sequence_gaps(seq)}'
    assert len(seq) == seq[-1] - seq[0] + 1
    steps = np.diff(stamps)
    assert np.all(steps > 0)
    assert np.median(steps) == pytest.approx(1_000_000, rel=0.1)
    # every command, in order
    assert duties == pytest.approx(sent)
    # what ros2 bag play and Foxglove need
    state = conns[STATE]
    assert state.msgdef.format == MessageDefinitionFormat.MSG
    assert state.ext.offered_qos_profiles[0].reliability == QosReliability.RELIABLE
    assert conns[DUTY].ext.offered_qos_profiles[0].reliability == QosReliability.RELIABLE
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    # the numpy loader sees the same
    data = load_bag(bag, topics=[STATE])
    np.testing.assert_array_equal(data[STATE]['sequence'], seq)
    assert 'closed' in rec.output and '0 messages lost before the recorder' in rec.output


def test_a_killed_recorder_leaves_a_bag_recoverable_to_its_last_flush(
        start_node, ros, tmp_path):
    bag = tmp_path / 'bag'
    run = _start_and_match(start_node, ros, bag)
    rec = run.rec
    for i in range(15):
        run.commands.send(round(0.05 * (i + 1), 3))
        ros.spin_for(0.2)
    sent = run.commands.sent
    flushed_before_kill = run.diag.int('flushed', 0)
    last_seen = run.probe.window().last
    rec.signal(signal.SIGKILL)
    rec.proc.wait(timeout=10)
    assert flushed_before_kill > 1000
    assert not (bag / 'metadata.yaml').exists()

    recover = start_node('valve_recorder', '--recover', str(bag), '-o', str(tmp_path / 'fixed'))
    assert recover.proc.wait(timeout=60) == 0, recover.output
    assert 'recovered' in recover.output
    got = _state_and_duties(tmp_path / 'fixed')
    seq, stamps, duties, conns = got.seq, got.stamps, got.duties, got.conns
    total = sum(c.msgcount for c in conns.values())
    assert total >= flushed_before_kill  # everything reported flushed is there
    assert np.all(np.diff(seq) == 1), f'sequence gaps: {sequence_gaps(seq)}'
    assert np.all(np.diff(stamps) > 0)
    assert len(duties) >= 5 and duties == pytest.approx(sent[:len(duties)])
    # the loss window: what the probe saw last vs. the last recovered state
    last_ns = last_seen.header.stamp.sec * 1_000_000_000 + last_seen.header.stamp.nanosec
    assert (last_ns - stamps[-1]) * 1e-9 < 2.0
    # the killed bag itself is readable up to the same point
    killed = load_bag(bag, topics=[STATE])
    np.testing.assert_array_equal(killed[STATE]['sequence'], seq)


def test_sigterm_closes_the_bag_and_bad_arguments_fail(start_node, ros, tmp_path):
    # no output: a bag named after the time inside output_dir (created)
    rec = start_node('valve_recorder', '--ros-args', '-p', f'output_dir:={tmp_path / "bags"}',
                     '-p', 'diagnostics_period_s:=0.2')
    poll_until(lambda: 'recording' in rec.output or not rec.alive(), 30.0,
               'the recorder to say it is recording')
    assert rec.alive(), rec.output
    diag = Diagnostics(ros.node('diagnostics_reader'), RECORDER_STATUS)
    # parameters are read at start; a change at run time is refused, saying so
    (result,) = ros.set_parameters('valve_recorder', {'flush_period_s': 0.1})
    assert not result.successful and 'restart' in result.reason
    ros.wait_for(lambda: diag.int('count /diagnostics', 0) >= 1, 30.0,
                 'the recorder receiving its own diagnostics')
    rec.signal(signal.SIGTERM)
    assert rec.proc.wait(timeout=20) == 0, rec.output
    (bag,) = (tmp_path / 'bags').glob('valve_*')
    assert (bag / 'metadata.yaml').is_file()
    assert '/diagnostics' in load_bag(bag)

    again = _start_recorder(start_node, bag)  # the bag exists: refused, never overwritten
    assert again.proc.wait(timeout=60) == 2  # refused input (the exit code rule)
    assert 'exists' in again.output
    bad = start_node('valve_recorder', '-o', str(tmp_path / 'b2'), 'x:nope_msgs/msg/Nope')
    assert bad.proc.wait(timeout=60) == 2
    assert 'nope_msgs/msg/Nope' in bad.output
    assert not (tmp_path / 'b2').exists()
