"""position_controller: moves the pneumatic cylinder by commanding valve mass flow.

- subscribes ``cylinder/joint_states`` (sensor_msgs/JointState, joint ``piston``);
- subscribes ``cylinder/position_goal`` (std_msgs/Float64, [m]): a new position to go to;
- publishes ``valve/flow_command`` (valve_msgs/FlowCommand) at ``rate_hz``;
- publishes ``cylinder/position_setpoint`` (std_msgs/Float64, [m]): the setpoint in force,
  so a recording shows what the controller was asked to do.

The control law (valve_model_pkg.pneumatics.controller) is PID on position with a bleed
feedforward, in mass flow; flow_to_duty turns the flow into PWM duty.
"""
from __future__ import annotations

import math

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from valve_msgs.msg import FlowCommand

from valve_model_pkg.interface import (TOPIC_JOINT_STATES, TOPIC_POSITION_GOAL,
                                       TOPIC_POSITION_SETPOINT)
from valve_model_pkg.interface.ros import JOINT_STATES_QOS
from valve_model_pkg.nodes.common import (COMMAND_QOS, TOPIC_FLOW_COMMAND, declare_bool,
                                          declare_float, run_node)
from valve_model_pkg.pneumatics.controller import ControllerGains, PositionController
from valve_model_pkg.pneumatics.cylinder import PARAMETER_INFO, CylinderParameters


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
        self._flow_pub = self.create_publisher(FlowCommand, TOPIC_FLOW_COMMAND, COMMAND_QOS)
        self._setpoint_pub = self.create_publisher(Float64, TOPIC_POSITION_SETPOINT, COMMAND_QOS)
        self.create_subscription(JointState, TOPIC_JOINT_STATES, self._on_joint,
                                 JOINT_STATES_QOS)
        self.create_subscription(Float64, TOPIC_POSITION_GOAL, self._on_goal, COMMAND_QOS)
        self.create_timer(1.0 / self._rate_hz, self._on_tick)

    def _on_goal(self, msg: Float64) -> None:
        goal = float(msg.data)
        if not math.isfinite(goal) or not 0.0 <= goal <= self._stroke_m:
            self.get_logger().warning(f'position goal {goal!r} m rejected: not within the '
                                      f'stroke [0, {self._stroke_m:g}] m; keeping '
                                      f'{self._setpoint_m:g} m')
            return
        self.get_logger().info(f'new position goal {goal * 1e3:.1f} mm')
        self._setpoint_m = goal

    def _on_joint(self, msg: JointState) -> None:
        try:
            i = list(msg.name).index('piston')
            position, velocity = float(msg.position[i]), float(msg.velocity[i])
        except (ValueError, IndexError):
            self.get_logger().warning('joint_states without a piston position/velocity; '
                                      'ignored', throttle_duration_sec=5.0)
            return
        if math.isfinite(position) and math.isfinite(velocity):
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
        msg.mass_flow = flow
        self._flow_pub.publish(msg)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(PositionControllerNode, 'position_controller', args)


if __name__ == '__main__':
    main()
