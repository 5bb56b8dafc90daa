"""The demo's own rclpy node: it sends goals, holds and releases the lockstep simulation,
and watches the suite's topics to print what happens."""
from __future__ import annotations

import math
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from valve_msgs.msg import DutyCommand, FlowCommand, ValveState

from valve_bringup.supervisor import Supervisor
from valve_model_pkg.interface import (TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_DUTY_COMMAND,
                                       TOPIC_FLOW_COMMAND, TOPIC_JOINT_STATES,
                                       TOPIC_OUTPUT_PRESSURE, TOPIC_POSITION_GOAL,
                                       TOPIC_POSITION_SETPOINT, TOPIC_REAL_TIME_FACTOR,
                                       TOPIC_RUN_UNTIL, TOPIC_STATE, gauge_from_absolute)
from valve_model_pkg.interface.ros import (CLOCK_QOS, COMMAND_QOS, DIAGNOSTICS_QOS,
                                           JOINT_STATES_QOS, PRESSURE_QOS, PROBE_QOS,
                                           STATE_QOS)
from valve_model_pkg.nodes.common import make_executor

__all__ = ['DISCOVERY_WAIT_S', 'DemoWatcher', 'suite_topics_in_use', 'valve_topic']


#: How long a probe listens for other participants before it judges the domain free [s].
#: Discovery on the loopback profile completes within a few hundred milliseconds; a
#: participant found later is still caught by the run's own checks (sequence gaps).
DISCOVERY_WAIT_S = 1.5


def suite_topics_in_use(wait_s: float = DISCOVERY_WAIT_S) -> list[str]:
    """Valve state topics on which another suite is publishing on this ROS domain.

    A second demo (or a suite already running) on the same ``ROS_DOMAIN_ID`` would mix its
    valve state and commands with this run's; the caller refuses to start instead. A topic
    counts only when a ``ValveState`` message arrives on it: a process that was killed
    stays in the discovery graph until its lease ends, but sends nothing.

    Parameters
    ----------
    wait_s : float
        Time granted to discovery and the first message [s]; the probe returns as soon as
        a message arrives. 0 skips the check.

    Returns
    -------
    list of str
        The topics on which a ``ValveState`` arrived, sorted.
    """
    if wait_s <= 0.0:
        return []
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('valve_demo_domain_probe', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        heard: set[str] = set()
        watched: set[str] = set()
        deadline = time.monotonic() + wait_s
        while not heard and time.monotonic() < deadline:
            for name, types in node.get_topic_names_and_types():
                if name not in watched and 'valve_msgs/msg/ValveState' in types:
                    watched.add(name)
                    node.create_subscription(ValveState, name,
                                             lambda _msg, n=name: heard.add(n),
                                             PROBE_QOS)
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
        node.destroy_node()
        return sorted(heard)
    finally:
        rclpy.try_shutdown(context=context)


def valve_topic(ns: str, topic: str) -> str:
    """``topic`` in the valve namespace ``ns`` ('' = none)."""
    return f'{ns}/{topic}' if ns else topic


class DemoWatcher:
    """The demo's node and its executor; :meth:`close` shuts rclpy down.

    Parameters
    ----------
    valve_ns : str
        Namespace of the valve whose topics are watched ('' = none).

    Attributes
    ----------
    states : int
        ``valve/state`` messages seen until :meth:`stop_watching_state`.
    position_m, pressure_pa : float
        Newest piston position [m] and chamber pressure, gauge [Pa] (NaN before any).
    clock_ns : int
        Newest simulation time [ns] (-1 before any).
    flow_stamp_ns : int
        Stamp of the newest flow command [ns]: in lockstep the tick the controller chain
        answered.
    setpoint_m : float
        The controller's newest setpoint [m]: its acknowledgement of a goal.
    rtf : float
        Newest real-time factor of the simulation.
    sim_values : dict of str to str
        Newest values of the lockstep simulation's diagnostics.
    recorder_values : dict of str to str
        Newest values of the recorder's diagnostics (``matched T``: publishers of topic T
        its subscription has matched).
    """

    def __init__(self, valve_ns: str = '') -> None:
        rclpy.init()
        self.probe = rclpy.create_node('valve_demo')
        # The C++ executor: this process takes /clock at 1 kHz beside the suite's nodes.
        self.executor, _ = make_executor(self.probe, events=True)
        self.executor.add_node(self.probe)
        self.states = 0
        self.position_m = math.nan
        self.pressure_pa = math.nan
        self.flow_stamp_ns = -1
        self.clock_ns = -1
        self.setpoint_m = math.nan
        self.rtf = math.nan
        self.sim_values: dict[str, str] = {}
        self.recorder_values: dict[str, str] = {}
        self._flow_sum, self._flow_n = 0.0, 0
        self._duty_sum, self._duty_n = 0.0, 0
        # valve/state only tells that the backend is up: 1 kHz in this process would take
        # CPU from the suite, so the subscription goes once the first state arrived.
        self._state_sub = self.probe.create_subscription(ValveState, TOPIC_STATE,
                                                         self._on_state, STATE_QOS)
        self._goal_pub = self.probe.create_publisher(Float64, TOPIC_POSITION_GOAL,
                                                     COMMAND_QOS)
        self._run_until_pub = self.probe.create_publisher(Float64, TOPIC_RUN_UNTIL,
                                                          COMMAND_QOS)
        subscriptions = (
            (JointState, TOPIC_JOINT_STATES, self._on_joint, JOINT_STATES_QOS),
            (FluidPressure, valve_topic(valve_ns, TOPIC_OUTPUT_PRESSURE), self._on_pressure,
             PRESSURE_QOS),
            (FlowCommand, valve_topic(valve_ns, TOPIC_FLOW_COMMAND), self._on_flow,
             COMMAND_QOS),
            (DutyCommand, valve_topic(valve_ns, TOPIC_DUTY_COMMAND), self._on_duty,
             COMMAND_QOS),
            (Clock, TOPIC_CLOCK, self._on_clock, CLOCK_QOS),
            (Float64, TOPIC_POSITION_SETPOINT, self._on_setpoint, COMMAND_QOS),
            (Float64, TOPIC_REAL_TIME_FACTOR, self._on_rtf, COMMAND_QOS),
            (DiagnosticArray, TOPIC_DIAGNOSTICS, self._on_diagnostics, DIAGNOSTICS_QOS))
        for msgtype, topic, callback, qos in subscriptions:
            self.probe.create_subscription(msgtype, topic, callback, qos)

    # --- callbacks ----------------------------------------------------------------------
    def _on_state(self, msg: ValveState) -> None:
        self.states += 1

    def _on_joint(self, msg: JointState) -> None:
        if msg.position:
            self.position_m = msg.position[0]

    def _on_pressure(self, msg: FluidPressure) -> None:
        self.pressure_pa = gauge_from_absolute(msg.fluid_pressure)

    def _on_flow(self, msg: FlowCommand) -> None:
        self._flow_sum += msg.mass_flow
        self._flow_n += 1
        self.flow_stamp_ns = max(self.flow_stamp_ns, msg.header.stamp.sec * 1_000_000_000
                                 + msg.header.stamp.nanosec)

    def _on_duty(self, msg: DutyCommand) -> None:
        self._duty_sum += msg.duty
        self._duty_n += 1

    def _on_clock(self, msg: Clock) -> None:
        self.clock_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec

    def _on_setpoint(self, msg: Float64) -> None:
        self.setpoint_m = msg.data

    def _on_rtf(self, msg: Float64) -> None:
        if msg.data > 0.0:
            self.rtf = msg.data

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if 'lockstep simulation' in status.name:
                self.sim_values = {kv.key: kv.value for kv in status.values}
            elif 'bag writer' in status.name:
                self.recorder_values = {kv.key: kv.value for kv in status.values}

    # --- what the demo does -------------------------------------------------------------
    def run_until(self, t_s: float) -> None:
        """Let the held simulation run until ``t_s`` [s of simulated time]."""
        self._run_until_pub.publish(Float64(data=float(t_s)))

    def goal(self, position_m: float) -> None:
        """Send a position goal [m]."""
        self._goal_pub.publish(Float64(data=float(position_m)))

    def subscribers(self, topic: str) -> int:
        """Subscriptions to ``topic`` in the graph, this watcher's own included."""
        return self.probe.count_subscribers(topic)

    def recorder_unmatched(self, topics: list[str]) -> list[str]:
        """Of ``topics``, those whose publishers in the graph the recorder has not all
        matched yet (one entry naming the recorder before its first diagnostics; topics
        it does not record are left out)."""
        if not self.recorder_values:
            return ['recorder (no diagnostics yet)']
        out = []
        for t in topics:
            matched, listed = self.recorder_values.get(f'matched {t}'), self.publishers(t)
            if matched is not None and int(matched) < listed:
                out.append(f'{t} (recorder matched {matched} of {listed})')
        return out

    def publishers(self, topic: str) -> int:
        """Publishers of ``topic`` in the graph."""
        return self.probe.count_publishers(topic)

    def stop_watching_state(self) -> None:
        """Drop the ``valve/state`` subscription (the backend is known to be up)."""
        if self._state_sub is not None:
            self.probe.destroy_subscription(self._state_sub)
            self._state_sub = None

    def reset(self) -> None:
        """Start new means of the commanded flow and duty (one step's)."""
        self._flow_sum = self._duty_sum = 0.0
        self._flow_n = self._duty_n = 0

    def spin_for(self, seconds: float, sup: Supervisor) -> None:
        """Spin for ``seconds`` of wall time; raise if a supervised process ended."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)
            sup.check_alive()

    def step_line(self, goal_m: float, extra: str = '') -> str:
        """One line of the demo's table: goal, position, error, chamber, means, ``extra``."""
        flow_cmd = self._flow_sum / self._flow_n if self._flow_n else math.nan
        duty = self._duty_sum / self._duty_n if self._duty_n else math.nan
        return (f'{goal_m * 1e3:6.1f}mm {self.position_m * 1e3:7.2f}mm '
                f'{(self.position_m - goal_m) * 1e3:+6.2f} {self.pressure_pa / 1e5:6.2f}bar '
                f'{flow_cmd * 1e3:6.3f}g/s {duty * 100:5.1f}%{extra}')

    def close(self) -> None:
        """Destroy the node and shut rclpy down."""
        self.executor.shutdown()
        self.probe.destroy_node()
        rclpy.try_shutdown()
