"""pneumatic_cylinder and position_controller survive any input and count what they refuse.

Hypothesis draws ValveState messages for the cylinder, JointState messages and position
goals for the controller (NaN, +-inf, negative, huge, 0, odd names and frame_ids, malformed
stamps, arrays of any length), published in bursts to the real node processes; each must
stay alive, keep publishing, and report in /diagnostics the rejections the test counts by
the rule of docs/safety.md, "Node inputs" (written here independently of the nodes).
"""
from __future__ import annotations

import math

import pytest
from hypothesis import strategies as st

from node_harness import Diagnostics
from robustness.node_fuzz import (any_float, collect, frame_ids, sequences, set_header, stamps,
                                  wait_counts)

pytestmark = pytest.mark.node

ATMOSPHERE_PA = 101_325.0
MAX_ABSOLUTE_PA = 1.0e7 + ATMOSPHERE_PA       # 100 bar gauge
X_MAX_M = 0.33e-3                             # the paper's valve stroke (config/valve.yaml)
STROKE_M = 0.1                                # the cylinder's default stroke
MAX_SPEED_M_S = 100.0
#: JointState's queue (cylinder/joint_states, keep last 50): bursts stay below it.
JOINT_CHUNK = 40


def valve_state_invalid(x: float, supply_gauge: float, nanosec: int) -> bool:
    if not (math.isfinite(x) and math.isfinite(supply_gauge)):
        return True
    if not -0.1 * X_MAX_M <= x <= 1.1 * X_MAX_M:
        return True
    if not 0.0 <= supply_gauge + ATMOSPHERE_PA <= MAX_ABSOLUTE_PA:
        return True
    return nanosec >= 10**9


def joint_invalid(names: list[str], pos: list[float], vel: list[float]) -> bool:
    if 'piston' not in names:
        return True
    i = names.index('piston')
    if i >= len(pos) or i >= len(vel):
        return True
    p, v = pos[i], vel[i]
    if not (math.isfinite(p) and math.isfinite(v)):
        return True
    return not (-0.1 * STROKE_M <= p <= 1.1 * STROKE_M and abs(v) <= MAX_SPEED_M_S)


def goal_invalid(goal: float) -> bool:
    return not math.isfinite(goal) or not 0.0 <= goal <= STROKE_M


valve_states = st.tuples(st.one_of(st.floats(0.0, X_MAX_M), any_float),
                         st.one_of(st.floats(-1e5, 1e6), any_float), any_float,
                         frame_ids, stamps, sequences)
floats_list = st.lists(st.one_of(st.floats(-0.01, 0.11), any_float), max_size=4)
joint_states = st.tuples(
    st.lists(st.sampled_from(['piston', '', 'rod', 'piston ']), max_size=4),
    floats_list, floats_list, floats_list, frame_ids, stamps)
goals = st.one_of(st.floats(0.0, STROKE_M), any_float)


def test_cylinder_survives_any_valve_state(start_node, ros):
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from valve_msgs.msg import ValveState

    from valve_model_pkg.interface import TOPIC_JOINT_STATES, TOPIC_STATE
    from valve_model_pkg.interface.ros import JOINT_STATES_QOS, STATE_QOS

    examples = collect(valve_states)
    node = start_node('pneumatic_cylinder', '--ros-args', '-p', 'diagnostics_period_s:=0.2')
    client = ros.add(Node('cylinder_fuzz'))
    diag = Diagnostics(client, 'cylinder plant')
    joints: list = []
    client.create_subscription(JointState, TOPIC_JOINT_STATES, joints.append, JOINT_STATES_QOS)
    pub = client.create_publisher(ValveState, TOPIC_STATE, STATE_QOS)
    ros.wait_matched([pub], f'pneumatic_cylinder\n{node.output[-2000:]}')
    wait_counts(ros, lambda: diag.count > 0, 'the cylinder diagnostics')

    expected = 0
    for x, supply, other, frame_id, stamp, seq in examples:   # the burst
        msg = set_header(ValveState(), frame_id, stamp)
        msg.spool_position, msg.supply_pressure, msg.sequence = x, supply, seq
        msg.coil_current = msg.mass_flow = msg.spool_velocity = other
        pub.publish(msg)
        expected += valve_state_invalid(x, supply, stamp[1])
    assert expected > 10

    rule_kinds = ('not_finite', 'position_out_of_range', 'pressure_out_of_range', 'bad_stamp')
    wait_counts(ros, lambda: diag.rejected('valve_state', rule_kinds) >= expected
                and diag.int('valve_states_used') + diag.rejected('valve_state')
                >= len(examples),
                f'{expected} rejections in the diagnostics (have {diag.values})')
    n = len(joints)
    wait_counts(ros, lambda: len(joints) > n + 10, 'joint states after the burst')
    assert node.alive(), node.output[-3000:]
    assert diag.rejected('valve_state', rule_kinds) == expected, diag.values
    last = joints[-1]
    assert all(math.isfinite(v) for v in (*last.position, *last.velocity, *last.effort))
    assert node.stop() == 0
    print(f'{len(examples)} valve states, {expected} invalid, node: {diag.values}')


def test_position_controller_survives_any_joint_state_and_goal(start_node, ros):
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from valve_msgs.msg import FlowCommand

    from valve_model_pkg.interface import (TOPIC_FLOW_COMMAND, TOPIC_JOINT_STATES,
                                           TOPIC_POSITION_GOAL)
    from valve_model_pkg.interface.ros import COMMAND_QOS, JOINT_STATES_QOS

    joint_examples = collect(joint_states)
    goal_examples = collect(goals)
    node = start_node('position_controller', '--ros-args', '-p', 'diagnostics_period_s:=0.2')
    client = ros.add(Node('controller_fuzz'))
    diag = Diagnostics(client, 'position control')
    flows: list = []
    client.create_subscription(FlowCommand, TOPIC_FLOW_COMMAND, flows.append, COMMAND_QOS)
    joint_pub = client.create_publisher(JointState, TOPIC_JOINT_STATES, JOINT_STATES_QOS)
    goal_pub = client.create_publisher(Float64, TOPIC_POSITION_GOAL, COMMAND_QOS)
    ros.wait_matched([joint_pub, goal_pub], f'position_controller\n{node.output[-2000:]}')
    wait_counts(ros, lambda: diag.count > 0, 'the controller diagnostics')

    expected_goals = 0
    for goal in goal_examples:                                   # one burst of goals
        goal_pub.publish(Float64(data=goal))
        expected_goals += goal_invalid(goal)
    expected_joints = 0
    for start in range(0, len(joint_examples), JOINT_CHUNK):     # bursts below the queue
        for names, pos, vel, eff, frame_id, stamp in joint_examples[start:start + JOINT_CHUNK]:
            msg = set_header(JointState(), frame_id, stamp)
            msg.name, msg.position, msg.velocity, msg.effort = names, pos, vel, eff
            joint_pub.publish(msg)
            expected_joints += joint_invalid(names, pos, vel)
        wait_counts(ros, lambda: diag.rejected('joint_states') >= expected_joints,
                    f'{expected_joints} joint state rejections (have {diag.values})')
    assert expected_goals > 5 and expected_joints > 10
    wait_counts(ros, lambda: diag.rejected('position_goal') >= expected_goals,
                f'{expected_goals} goal rejections (have {diag.values})')
    ros.spin_for(0.5)
    assert node.alive(), node.output[-3000:]
    assert diag.rejected('position_goal') == expected_goals, diag.values
    assert diag.rejected('joint_states') == expected_joints, diag.values

    # still controlling: valid feedback gives finite flow commands with rising sequence
    n = len(flows)
    for _ in range(20):
        joint_pub.publish(JointState(name=['piston'], position=[0.05], velocity=[0.0]))
        ros.spin(0.02)
    wait_counts(ros, lambda: len(flows) > n + 5, 'flow commands after the burst')
    assert all(math.isfinite(f.mass_flow) for f in flows[n:])
    seqs = [f.sequence for f in flows[n:]]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert node.stop() == 0
    print(f'{len(goal_examples)} goals ({expected_goals} invalid), {len(joint_examples)} '
          f'joint states ({expected_joints} invalid), node: {diag.values}')
