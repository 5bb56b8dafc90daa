"""flow_to_duty survives any flow command and pressure message, and counts what it refuses.

Hypothesis draws FlowCommand and FluidPressure messages (NaN, +-inf, negative, huge, 0,
odd frame_ids, malformed stamps, any sequence), published in one burst to the real node
process; it must stay alive, still answer a valid command, and report in /diagnostics the
rejections the test counts by the rule of docs/safety.md, "Node inputs" (written here
independently of the node).
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
MAX_FLOW_KG_S = 1.0


def flow_invalid(kg_s: float, nanosec: int) -> bool:
    return not math.isfinite(kg_s) or not 0.0 <= kg_s <= MAX_FLOW_KG_S or nanosec >= 10**9


def pressure_invalid(absolute_pa: float, nanosec: int) -> bool:
    return (not math.isfinite(absolute_pa) or not 0.0 <= absolute_pa <= MAX_ABSOLUTE_PA
            or nanosec >= 10**9)


flows = st.tuples(st.just('flow'), st.one_of(st.floats(0.0, 5e-3), any_float), any_float,
                  frame_ids, stamps, sequences)
pressures = st.tuples(st.sampled_from(['supply', 'output']),
                      st.one_of(st.floats(0.0, 1.2e6), any_float), any_float, frame_ids,
                      stamps, sequences)


def test_any_input_is_survived_and_counted(start_node, ros):
    from rclpy.node import Node
    from sensor_msgs.msg import FluidPressure
    from valve_msgs.msg import FlowCommand, FlowToDutyStatus

    from valve_model_pkg.nodes.common import (COMMAND_QOS, PRESSURE_QOS, TOPIC_FLOW_COMMAND,
                                              TOPIC_FLOW_STATUS, TOPIC_OUTPUT_PRESSURE,
                                              TOPIC_SUPPLY_PRESSURE)

    examples = collect(st.one_of(flows, pressures))
    node = start_node('flow_to_duty', '--ros-args', '-p', 'diagnostics_period_s:=0.2')
    client = ros.add(Node('flow_to_duty_fuzz'))
    diag = Diagnostics(client, 'flow to duty')
    statuses: list = []
    client.create_subscription(FlowToDutyStatus, TOPIC_FLOW_STATUS, statuses.append,
                               COMMAND_QOS)
    flow_pub = client.create_publisher(FlowCommand, TOPIC_FLOW_COMMAND, COMMAND_QOS)
    pubs = {'supply': client.create_publisher(FluidPressure, TOPIC_SUPPLY_PRESSURE,
                                              PRESSURE_QOS),
            'output': client.create_publisher(FluidPressure, TOPIC_OUTPUT_PRESSURE,
                                              PRESSURE_QOS)}
    ros.wait_matched([flow_pub, *pubs.values()], f'flow_to_duty\n{node.output[-2000:]}')
    wait_counts(ros, lambda: diag.count > 0, 'the flow_to_duty diagnostics')

    expected = {'flow_command': 0, 'supply_pressure': 0, 'output_pressure': 0}
    n_flows = 0
    for kind, a, b, frame_id, stamp, seq in examples:          # the burst
        if kind == 'flow':
            msg = set_header(FlowCommand(), frame_id, stamp)
            msg.mass_flow, msg.sequence = a, seq
            flow_pub.publish(msg)
            expected['flow_command'] += flow_invalid(a, stamp[1])
            n_flows += 1
        else:
            msg = set_header(FluidPressure(), frame_id, stamp)
            msg.fluid_pressure, msg.variance = a, b
            pubs[kind].publish(msg)
            expected[f'{kind}_pressure'] += pressure_invalid(a, stamp[1])
    assert sum(expected.values()) > 10, expected

    rule_kinds = ('not_finite', 'out_of_range', 'bad_stamp')
    wait_counts(ros, lambda: diag.int('commands') >= n_flows
                and all(diag.rejected(k, rule_kinds) >= n for k, n in expected.items()),
                f'{n_flows} commands and rejections {expected} in the diagnostics '
                f'(have {diag.values})')
    ros.spin_for(0.5)
    assert node.alive(), node.output[-3000:]
    for name, n in expected.items():
        assert diag.rejected(name, rule_kinds) == n, (name, diag.values)
    # a flow the map cannot convert is rejected too: at least the rule's count
    assert diag.int('rejected') >= expected['flow_command']
    assert diag.int('bad_pressure_messages') == (expected['supply_pressure']
                                                 + expected['output_pressure'])
    assert diag.int('commands') == n_flows

    # still answering: sane pressures, then a valid command gets a valid duty
    for port, gauge in (('supply', 4.0e5), ('output', 0.0)):
        pubs[port].publish(FluidPressure(fluid_pressure=gauge + ATMOSPHERE_PA))
    ros.spin_for(0.3)
    n = len(statuses)
    flow_pub.publish(FlowCommand(mass_flow=1.0e-3))
    wait_counts(ros, lambda: any(s.requested_mass_flow == pytest.approx(1.0e-3)
                                 for s in statuses[n:]), 'the answer to a valid command')
    answer = [s for s in statuses[n:] if s.requested_mass_flow == pytest.approx(1.0e-3)][-1]
    assert answer.status != FlowToDutyStatus.STATUS_REJECTED
    assert 0.0 <= answer.duty <= 1.0
    assert node.alive() and node.stop() == 0
    print(f'{len(examples)} messages, rejections expected {expected}, node counts '
          f'{ {k: v for k, v in diag.values.items() if "reject" in k} }')
