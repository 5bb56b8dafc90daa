"""valve_lockstep_sim with an external valve: while a step waits for the valve's state, the
simulation publishes the tick's pressure and joint state again, so a tick answer lost on
its way to the valve's side (the CAN emulator's clock bridge waits for the tick's duty
command and pressure before it advances) comes again, and the run goes on without a
lockstep timeout.

The test plays the valve's side and the controller chain: it answers each step request
(``/clock``) with one ``valve/state`` and each tick with its duty command, and holds back
the state of the step after the first control tick until the tick's messages came a second
time. Asserts messages and counts, not a timing: the lockstep timeout is far longer than
the test's waits.
"""
from __future__ import annotations

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from valve_msgs.msg import DutyCommand, ValveState

from valve_model_pkg.interface import (TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_DUTY_COMMAND,
                                       TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE,
                                       TOPIC_RUN_UNTIL, TOPIC_STATE)
from valve_model_pkg.interface.ros import (CLOCK_QOS, COMMAND_QOS, DIAGNOSTICS_QOS,
                                           JOINT_STATES_QOS, PRESSURE_QOS, STATE_DURABLE_QOS)

pytestmark = pytest.mark.node

#: Far longer than any wait of the test: a resend is no timeout [s].
TIMEOUT_S = 60.0
STEP_NS = 1_000_000
TICK_NS = 5_000_000
#: Two control ticks [s].
RUN_UNTIL_S = 0.010


def _ns(stamp) -> int:  # noqa: ANN001 - builtin_interfaces/Time
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class _ValveSide:
    """The test's node: the external valve (states) and the controller chain (duties)."""

    def __init__(self, node) -> None:  # noqa: ANN001 - an rclpy Node
        self.node = node
        self.clock_ns = -1
        self.ticks: dict[str, list[int]] = {'pressure': [], 'joint': []}
        self.values: dict[str, str] = {}
        self.sequence = 0        # of the duty commands
        self.state_sequence = 0
        # as the CAN driver publishes (the simulation reads an external valve durably)
        self.state_pub = node.create_publisher(ValveState, TOPIC_STATE, STATE_DURABLE_QOS)
        self.duty_pub = node.create_publisher(DutyCommand, TOPIC_DUTY_COMMAND, COMMAND_QOS)
        self.run_until = node.create_publisher(Float64, TOPIC_RUN_UNTIL, COMMAND_QOS)
        node.create_subscription(Clock, TOPIC_CLOCK, self._on_clock, CLOCK_QOS)
        node.create_subscription(FluidPressure, TOPIC_OUTPUT_PRESSURE,
                                 lambda m: self.ticks['pressure'].append(_ns(m.header.stamp)),
                                 PRESSURE_QOS)
        node.create_subscription(JointState, TOPIC_JOINT_STATES, self._on_joint,
                                 JOINT_STATES_QOS)
        node.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self._on_diagnostics,
                                 DIAGNOSTICS_QOS)

    def _on_clock(self, msg: Clock) -> None:
        self.clock_ns = max(self.clock_ns, _ns(msg.clock))

    def _on_joint(self, msg: JointState) -> None:
        stamp = _ns(msg.header.stamp)
        self.ticks['joint'].append(stamp)
        duty = DutyCommand(duty=0.0, pwm_frequency=50.0, sequence=self.sequence)
        duty.header.stamp = msg.header.stamp    # the tick's answer (flow_to_duty's stamp)
        duty.header.frame_id = self.node.get_fully_qualified_name()
        self.duty_pub.publish(duty)
        self.sequence += 1

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if 'lockstep simulation' in status.name:
                self.values = {kv.key: kv.value for kv in status.values}

    def send_state(self, t_ns: int) -> None:
        """The valve's state at ``t_ns`` (closed: the cylinder stays where it is)."""
        msg = ValveState(spool_position=0.0, sequence=self.state_sequence)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
        self.state_pub.publish(msg)
        self.state_sequence += 1

    def count(self, kind: str, tick_ns: int) -> int:
        return self.ticks[kind].count(tick_ns)


def test_a_step_waiting_for_the_valve_sends_the_tick_again(start_node, ros):
    sim = start_node('valve_lockstep_sim', '--ros-args', '-p', 'start_paused:=true',
                     '-p', 'real_time_factor_max:=0.0', '-p', 'valve_source:=external',
                     '-p', f'lockstep_timeout_s:={TIMEOUT_S}',
                     '-p', 'diagnostics_period_s:=0.2')
    side = _ValveSide(ros.node('external_valve_side'))
    ros.wait_matched([side.state_pub, side.duty_pub, side.run_until], 'the simulation')
    # The start handshake: the t = 0 state once the simulation's clock shows at 0.
    ros.wait_for(lambda: side.clock_ns == 0, 60.0, 'the simulation\'s clock at t = 0')
    side.send_state(0)
    ros.wait_for(lambda: side.values.get('start_handshake') == 'done', 60.0,
                 'the start handshake')
    answered = 0

    def run_to(until_ns: int, hold_back_ns: int | None = None) -> None:
        """Answer each step request up to ``until_ns``; stop at ``hold_back_ns``."""
        side.run_until.publish(Float64(data=RUN_UNTIL_S))

        def step_answered() -> bool:
            nonlocal answered
            if side.clock_ns > answered and side.clock_ns != hold_back_ns:
                answered = side.clock_ns
                side.send_state(answered)
            return answered >= until_ns or side.clock_ns == hold_back_ns
        ros.wait_for(step_answered, 60.0, f'the simulation\'s steps up to {until_ns} ns')

    # Up to the step after the first tick: its state is held back.
    run_to(TICK_NS + STEP_NS, hold_back_ns=TICK_NS + STEP_NS)
    assert side.count('pressure', TICK_NS) == 1 and side.count('joint', TICK_NS) == 1
    # Waiting for that state, the simulation sends the tick's pressure and joint state
    # again (and the controller chain, here the test, answers them again).
    ros.wait_for(lambda: side.count('pressure', TICK_NS) >= 2
                 and side.count('joint', TICK_NS) >= 2, 30.0,
                 'tick 5 ms\'s pressure and joint state sent again')
    assert side.clock_ns == TICK_NS + STEP_NS   # the clock never goes back to the tick
    run_to(int(RUN_UNTIL_S * 1e9))
    ros.wait_for(lambda: int(side.values.get('steps', '0')) >= 10, 30.0,
                 'the simulation at 10 ms')
    assert int(side.values['lockstep_timeouts']) == 0, side.values
    assert int(side.values['stale_duty_answers']) == 0, side.values
    # An answer to an older tick, coming again late: not applied, and counted.
    old = DutyCommand(duty=1.0, pwm_frequency=50.0, sequence=side.sequence)
    old.header.frame_id = side.node.get_fully_qualified_name()
    side.sequence += 1
    side.duty_pub.publish(old)   # stamped t = 0
    ros.wait_for(lambda: int(side.values.get('stale_duty_answers', '0')) == 1, 30.0,
                 'the stale answer counted')
    assert int(side.values['rejected_messages']) == 0, side.values
    assert sim.alive(), sim.output[-2000:]
