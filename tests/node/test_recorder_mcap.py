"""A bag recorded by the valve_recorder node, read by the MCAP project's reader and decoder."""
from __future__ import annotations

import pytest
import yaml

from valve_model_pkg.nodes.probe import StateProbe
from valve_model_pkg.recording import load_bag

from node_harness import Diagnostics, DutyCommander

# lark (used by mcap-ros2-support to parse .msg) imports deprecated sre modules
pytestmark = [pytest.mark.node,
              pytest.mark.filterwarnings('ignore::DeprecationWarning:lark.utils')]

STATE = '/valve/state'
DUTY = '/valve/duty_command'
#: States the bag holds at least before the recorder is stopped.
MIN_STATES = 500


def test_recorded_bag_decodes_message_by_message(start_node, ros, tmp_path) -> None:
    # imported here, under the warning filter (lark imports deprecated modules)
    make_reader = pytest.importorskip('mcap.reader').make_reader
    decoder_factory = pytest.importorskip('mcap_ros2.decoder').DecoderFactory
    bag = tmp_path / 'bag'
    start_node('valve_simulator', '--ros-args', '-p', 'publish_rate_hz:=1000.0')
    rec = start_node('valve_recorder', '-o', str(bag), STATE, DUTY, '--ros-args',
                     '-p', 'flush_period_s:=0.5', '-p', 'diagnostics_period_s:=0.2')
    probe = ros.add(StateProbe('test_probe'))
    commands = DutyCommander(probe)
    recorded = Diagnostics(probe, 'valve_recorder: bag writer')
    ros.wait_for(lambda: probe.count > 10, 30.0, 'valve/state from the simulator')
    ros.wait_matched([commands.publisher], 'simulator and recorder', count=2, timeout_s=30.0)
    sent = [0.2, 0.4, 0.6]
    for duty in sent:
        commands.send(duty)
        ros.spin_for(0.3)
    ros.wait_for(lambda: recorded.int(f'count {DUTY}', 0) >= len(sent), 30.0,
                 f'the recorder counting {len(sent)} duty commands ({recorded.values})')
    # a bag of some length, counted by the recorder (not a wall-time share of 1 kHz)
    ros.wait_for(lambda: recorded.int(f'count {STATE}', 0) > MIN_STATES, 60.0,
                 f'the recorder counting {MIN_STATES} states ({recorded.values})')
    assert rec.stop() == 0, rec.output[-3000:]

    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['ros_distro'] == 'jazzy'
    written = {t['topic_metadata']['name']: t['message_count']
               for t in info['topics_with_message_count']}
    hashes = {t['topic_metadata']['name']: t['topic_metadata']['type_description_hash']
              for t in info['topics_with_message_count']}
    counts = {topic: 0 for topic in written}
    duties = []
    with open(bag / 'bag.mcap', 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[decoder_factory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            assert channel.metadata['topic_type_hash'] == hashes[channel.topic]
            assert 'offered_qos_profiles' in channel.metadata
            if channel.topic == DUTY:
                duties.append(decoded.duty)
    assert counts == written
    assert counts[STATE] > MIN_STATES
    assert duties == pytest.approx(sent)
    # the suite's own loader (rosbags) sees the same messages
    assert len(load_bag(bag, topics=[STATE])[STATE]) == counts[STATE]
