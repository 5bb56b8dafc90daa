"""position_controller: moves the pneumatic cylinder by commanding valve mass flow.

- subscribes ``cylinder/joint_states`` (sensor_msgs/JointState, joint ``piston``);
- subscribes ``cylinder/position_goal`` (std_msgs/Float64, [m]): a new position to go to;
- publishes ``valve/flow_command`` (valve_msgs/FlowCommand) at ``rate_hz``;
- publishes ``cylinder/position_setpoint`` (std_msgs/Float64, [m]): the setpoint in force,
  so a recording shows what the controller was asked to do;
- publishes ``/diagnostics`` once per ``diagnostics_period_s``: commands sent, rejected
  inputs per kind.

Every flow command carries this node's ``sequence`` (+1 per message) and its fully
qualified name as ``header.frame_id``, so flow_to_duty can report lost commands.

No message ends the node (docs/safety.md, "Node inputs"): a goal outside the stroke or not
finite, a joint state without the piston, with a non-finite value, a position outside the
stroke by more than 10 % of it or a speed above ``MAX_PISTON_SPEED_M_S`` is rejected with a
warning (the first of each kind always, then at most one per second per kind) and counted;
the last valid value stays.

The control law (valve_model_pkg.pneumatics.controller) is PID on position with a bleed
feedforward, in mass flow; flow_to_duty turns the flow into PWM duty.
"""
from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from valve_msgs.msg import FlowCommand

from valve_model_pkg.interface import (TOPIC_DIAGNOSTICS, TOPIC_JOINT_STATES,
                                       TOPIC_POSITION_GOAL, TOPIC_POSITION_SETPOINT)
from valve_model_pkg.interface.ros import DIAGNOSTICS_QOS, JOINT_STATES_QOS
from valve_model_pkg.nodes.common import (COMMAND_QOS, TOPIC_FLOW_COMMAND, DiagnosticLevel,
                                          declare_bool, declare_float, key_values, run_node)
from valve_model_pkg.nodes.inputs import InputGuard
from valve_model_pkg.pneumatics.controller import ControllerGains, PositionController
from valve_model_pkg.pneumatics.cylinder import PARAMETER_INFO, CylinderParameters

#: Fastest plausible piston speed [m/s]; pneumatic cylinders run below about 10 m/s.
MAX_PISTON_SPEED_M_S = 100.0
#: A measured position may lie this fraction of the stroke beyond either end [1].
POSITION_MARGIN = 0.1


class PositionControllerNode(Node):
    """PID position control of the cylinder through flow commands."""

    def __init__(self) -> None:
        super().__init__('position_controller')
        g = ControllerGains()
        gains = ControllerGains(
            kp_kg_s_per_m=declare_float(self, 'kp_kg_s_per_m', g.kp_kg_s_per_m,
                                        'Proportional gain [kg/s per m]', 0.0, 10.0),
            ki_kg_s_per_m_s=declare_float(self, 'ki_kg_s_per_m_s', g.ki_kg_s_per_m_s,
                                          'Integral gain [kg/s per m s]', 0.0, 100.0),
            kd_kg_per_m=declare_float(self, 'kd_kg_per_m', g.kd_kg_per_m,
                                      'Derivative (velocity) gain [kg/s per m/s]', 0.0, 10.0),
            max_mass_flow_kg_s=declare_float(self, 'max_mass_flow_kg_s',
                                             g.max_mass_flow_kg_s,
                                             'Largest flow command [kg/s]', 0.0, 1.0),
            feedforward=declare_bool(self, 'feedforward', True,
                                     'Add the bleed flow at the setpoint\'s pressure'))
        # The feedforward needs the plant's model: the same parameters as the cylinder's.
        defaults = CylinderParameters()
        plant = {name: declare_float(self, f'plant.{name}', getattr(defaults, name), text,
                                     low, high)
                 for name, (text, low, high) in PARAMETER_INFO.items()}
        self._controller = PositionController(gains, CylinderParameters(**plant))
        self._rate_hz = declare_float(self, 'rate_hz', 200.0, 'Control rate [Hz]', 1.0, 2000.0)
        self._setpoint_m = declare_float(self, 'initial_setpoint_m', 0.0,
                                         'Setpoint until a goal arrives [m]', 0.0, 2.0)
        self._stroke_m = plant['stroke_m']
        self._position_m: float | None = None
        self._velocity_m_s = 0.0
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the diagnostics summary [s]', 0.05, 60.0)
        self._inputs = InputGuard(self.get_logger())
        self._sequence = 0  # of the next flow command
        self._flow_pub = self.create_publisher(FlowCommand, TOPIC_FLOW_COMMAND, COMMAND_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS,
                                               DIAGNOSTICS_QOS)
        self._setpoint_pub = self.create_publisher(Float64, TOPIC_POSITION_SETPOINT, COMMAND_QOS)
        self.create_subscription(JointState, TOPIC_JOINT_STATES, self._on_joint,
                                 JOINT_STATES_QOS)
        self.create_subscription(Float64, TOPIC_POSITION_GOAL, self._on_goal, COMMAND_QOS)
        self.create_timer(1.0 / self._rate_hz, self._on_tick)
        self.create_timer(diag_period, self._publish_diagnostics)

    def _on_goal(self, msg: Float64) -> None:
        goal = float(msg.data)
        if not math.isfinite(goal) or not 0.0 <= goal <= self._stroke_m:
            self._inputs.reject('position_goal',
                                'out_of_range' if math.isfinite(goal) else 'not_finite',
                                f'position goal {goal!r} m rejected: not within the stroke '
                                f'[0, {self._stroke_m:g}] m; keeping {self._setpoint_m:g} m')
            return
        self.get_logger().info(f'new position goal {goal * 1e3:.1f} mm')
        self._setpoint_m = goal

    def _on_joint(self, msg: JointState) -> None:
        """Take the piston's position and velocity; refuse (and count) what is implausible."""
        keep = '; keeping the last valid feedback'
        try:
            i = list(msg.name).index('piston')
            position, velocity = float(msg.position[i]), float(msg.velocity[i])
        except (ValueError, IndexError):
            self._inputs.reject('joint_states', 'no_piston',
                                'joint_states without a piston position/velocity' + keep)
            return
        if not (math.isfinite(position) and math.isfinite(velocity)):
            self._inputs.reject('joint_states', 'not_finite',
                                f'joint_states piston position {position!r} m / velocity '
                                f'{velocity!r} m/s not finite' + keep)
            return
        margin = POSITION_MARGIN * self._stroke_m
        if not (-margin <= position <= self._stroke_m + margin
                and abs(velocity) <= MAX_PISTON_SPEED_M_S):
            self._inputs.reject('joint_states', 'out_of_range',
                                f'joint_states piston position {position!r} m / velocity '
                                f'{velocity!r} m/s outside [{-margin:g}, '
                                f'{self._stroke_m + margin:g}] m / '
                                f'{MAX_PISTON_SPEED_M_S:g} m/s' + keep)
            return
        self._position_m, self._velocity_m_s = position, velocity

    def _on_tick(self) -> None:
        setpoint = Float64(data=self._setpoint_m)
        self._setpoint_pub.publish(setpoint)
        if self._position_m is None:
            return  # no feedback yet: command nothing rather than guess
        flow = self._controller.update(self._setpoint_m, self._position_m,
                                       self._velocity_m_s, 1.0 / self._rate_hz)
        msg = FlowCommand()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.get_fully_qualified_name()
        msg.sequence = self._sequence
        msg.mass_flow = flow
        self._flow_pub.publish(msg)
        self._sequence += 1

    def _publish_diagnostics(self) -> None:
        level, text = DiagnosticLevel.OK, 'controlling'
        if self._position_m is None:
            level, text = DiagnosticLevel.WARN, 'no piston feedback yet: no flow commanded'
        if self._inputs.total:
            level = DiagnosticLevel.WARN
            text = f'{self._inputs.total} message(s) rejected; last: {self._inputs.last_reason}'
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: position control',
                                  message=text, hardware_id='cylinder')
        status.values = key_values(
            flow_commands_sent=self._sequence, setpoint_m=self._setpoint_m,
            rejected_messages=self._inputs.total, **self._inputs.diagnostic_values())
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(PositionControllerNode, 'position_controller', args)


if __name__ == '__main__':
    main()
