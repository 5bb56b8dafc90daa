"""valve_bank_simulator: 4 valves in one process, each at its rate, commands kept apart."""
from __future__ import annotations

import pytest
from suite_waits import SCHEDULING_ALLOWANCE_S, TEST_READER_DEPTH
from valve_msgs.msg import DutyCommand, ValveState

from valve_model_pkg.interface.ros import state_reader_qos
from valve_model_pkg.nodes.common import COMMAND_QOS

pytestmark = pytest.mark.node

NAMES = ['left_a', 'left_b', 'right_a', 'right_b']


def test_four_valves_each_at_rate_and_commands_reach_only_their_valve(start_node, ros):
    sim = start_node('valve_bank_simulator', '--ros-args', '-p',
                     f'valve_names:=[{",".join(NAMES)}]', '-p', 'publish_rate_hz:=500.0')
    node = ros.add(__import__('rclpy').create_node('bank_probe'))
    last: dict[str, ValveState] = {}
    counts = {n: 0 for n in NAMES}
    gaps = {n: 0 for n in NAMES}
    stamps: dict[str, list[float]] = {n: [] for n in NAMES}

    def on_state(name: str):
        def cb(msg: ValveState) -> None:
            prev = last.get(name)
            if prev is not None and msg.sequence != prev.sequence + 1:
                gaps[name] += 1
            last[name] = msg
            counts[name] += 1
            stamps[name].append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
        return cb
    # the states of the whole test kept while the test process is held up (STATE_QOS's
    # policies, a deeper queue): a gap counted is then the node's
    qos = state_reader_qos(TEST_READER_DEPTH)
    for n in NAMES:
        node.create_subscription(ValveState, f'{n}/valve/state', on_state(n), qos)
    cmd = node.create_publisher(DutyCommand, f'{NAMES[2]}/valve/duty_command', COMMAND_QOS)
    ros.wait_for(lambda: all(c > 10 for c in counts.values()), 60.0,
                 'valve/state of every valve')

    for n in NAMES:
        stamps[n].clear()
    ros.spin_for(3.0)
    for n in NAMES:  # each valve's own stream, on the model's 500 Hz sample grid
        steps = [(b - a) * 500.0 for a, b in zip(stamps[n], stamps[n][1:])]
        assert len(steps) > 10, (n, sim.output[-2000:])
        # one period, or whole periods the loop skipped when the process was held up (the
        # shared TickLoop reports them: test_simulator_node checks it)
        assert all(abs(k - round(k)) < 1e-3 and round(k) >= 1 for k in steps), (n, steps)
        assert last[n].header.frame_id == n
        assert last[n].source == ValveState.SOURCE_SIMULATOR
    ros.wait_for(lambda: cmd.get_subscription_count() > 0, 10.0, 'command subscriber')
    msg = DutyCommand()
    msg.header.frame_id = 'bank_probe'
    msg.duty = 0.6
    msg.pwm_frequency = 50.0
    cmd.publish(msg)
    # valve 2 takes the duty and opens (its states, in order, as far as the test has read)
    ros.wait_for(lambda: last[NAMES[2]].duty == pytest.approx(0.6)
                 and last[NAMES[2]].spool_position_avg > 0.0, SCHEDULING_ALLOWANCE_S,
                 f'{NAMES[2]} at duty 0.6 and opening')
    for n in (NAMES[0], NAMES[1], NAMES[3]):          # the others stay closed at duty 0
        assert last[n].duty == 0.0
        assert last[n].spool_position_avg == 0.0
        assert last[n].coil_current == 0.0
    assert gaps == {n: 0 for n in NAMES}
    assert sim.alive()
    assert sim.stop() == 0


def test_bad_valve_names_are_refused_with_exit_2(start_node):
    sim = start_node('valve_bank_simulator', '--ros-args', '-p', 'valve_names:=[a,a]')
    assert sim.proc.wait(timeout=60) == 2
    assert 'given more than once' in sim.output
