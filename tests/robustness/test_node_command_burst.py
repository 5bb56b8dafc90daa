"""Nothing lost unreported: a burst of 20 000 commands is processed or reported as lost.

The test publishes N commands as fast as it can, numbered 1..N after a first command 0 that
the node has counted (so the node's per-publisher baseline is set), and reads the node's
counts from /diagnostics: received (processed) + lost (sequence gaps) must equal N within
1 %. The last command is always delivered (keep-last keeps the newest), so every loss is
a gap the node can see. docs/safety.md, "Node inputs".
"""
from __future__ import annotations

import pytest

from node_harness import Diagnostics
from robustness.node_fuzz import wait_counts

pytestmark = [pytest.mark.node, pytest.mark.slow]

N = 20_000


def _burst(harness, diag: Diagnostics, pub, make, prefix: str, what: str) -> tuple[int, int]:
    """Send 0, wait until counted, then 1..N; return (processed, lost) of the burst."""
    pub.publish(make(0))
    wait_counts(harness, lambda: diag.int(f'{prefix}_received') >= 1, f'{what}: command 0 counted')
    harness.spin_for(0.5)
    received0, lost0 = diag.int(f'{prefix}_received'), diag.int(f'{prefix}_lost')
    sent = 0
    for seq in range(1, N + 1):
        pub.publish(make(seq))
        sent += 1
    assert sent == N
    wait_counts(harness, lambda: (diag.int(f'{prefix}_received') - received0)
                + (diag.int(f'{prefix}_lost') - lost0) >= N,
                f'{what}: the node to account for all {N} commands (have {diag.values})',
                timeout_s=300.0)
    harness.spin_for(1.0)
    processed = diag.int(f'{prefix}_received') - received0
    lost = diag.int(f'{prefix}_lost') - lost0
    print(f'{what}: sent {N}, processed {processed}, reported lost {lost}, '
          f'sum {processed + lost}, out of order {diag.int(f"{prefix}_out_of_order")}')
    return processed, lost


# serial: the test's own subscriber must keep up with the node's answer to the burst
# (beside a CPU-bound test under pytest-xdist it saw duty commands up to 3594 of 4263).
@pytest.mark.serial
def test_flow_to_duty_accounts_for_every_flow_command(start_node, ros):
    from rclpy.node import Node
    from valve_msgs.msg import DutyCommand, FlowCommand

    from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_FLOW_COMMAND
    from valve_model_pkg.interface.ros import COMMAND_QOS

    node = start_node('flow_to_duty', '--ros-args', '-p', 'diagnostics_period_s:=0.2',
                      '-p', 'republish_period_s:=0.0')
    client = ros.add(Node('flow_burst'))
    diag = Diagnostics(client, 'flow to duty')
    duties: list[int] = []
    client.create_subscription(DutyCommand, TOPIC_DUTY_COMMAND,
                               lambda m: duties.append(m.sequence), COMMAND_QOS)
    pub = client.create_publisher(FlowCommand, TOPIC_FLOW_COMMAND, COMMAND_QOS)
    ros.wait_matched([pub], f'flow_to_duty\n{node.output[-2000:]}')

    def make(seq: int) -> FlowCommand:
        msg = FlowCommand(sequence=seq, mass_flow=1.0e-4 * (seq % 20))
        msg.header.frame_id = 'burst_test'
        return msg

    processed, lost = _burst(ros, diag, pub, make, 'flow_commands', 'flow_to_duty')
    assert processed + lost == pytest.approx(N, rel=0.01)
    assert diag.int('flow_commands_out_of_order') == 0
    # each processed (valid) command was answered by one duty command of its own sequence
    wait_counts(ros, lambda: diag.int('duty_commands_sent') >= processed + 1,
                'the duty commands of every processed flow command')
    assert diag.int('duty_commands_sent') == diag.int('commands')
    assert duties and max(duties) + 1 == diag.int('duty_commands_sent')
    assert node.alive() and node.stop() == 0


def test_simulator_accounts_for_every_duty_command(start_node, ros):
    from valve_msgs.msg import DutyCommand

    from valve_model_pkg.interface import TOPIC_DUTY_COMMAND
    from valve_model_pkg.interface.ros import COMMAND_QOS
    from valve_model_pkg.nodes.probe import StateProbe

    sim = start_node('valve_simulator', '--ros-args', '-p', 'diagnostics_period_s:=0.2',
                     '-p', 'publish_rate_hz:=200.0')
    probe = ros.add(StateProbe('duty_burst'))
    diag = Diagnostics(probe, 'real-time model')
    pub = probe.create_publisher(DutyCommand, TOPIC_DUTY_COMMAND, COMMAND_QOS)
    ros.wait_for(lambda: probe.count > 10, 60.0, f'valve/state\n{sim.output[-2000:]}')
    ros.wait_matched([pub], 'valve_simulator')

    def make(seq: int) -> DutyCommand:
        msg = DutyCommand(sequence=seq, duty=(seq % 10) / 10.0, pwm_frequency=50.0)
        msg.header.frame_id = 'burst_test'
        return msg

    processed, lost = _burst(ros, diag, pub, make, 'duty_commands', 'valve_simulator')
    assert processed + lost == pytest.approx(N, rel=0.01)
    assert diag.int('duty_commands_out_of_order') == 0
    assert diag.int('duty_commands_rejected') == 0
    assert sim.alive() and sim.stop() == 0
