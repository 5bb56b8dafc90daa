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

The control law (valve_model_pkg.pneumatics.controller): by default a cascade -- position
error -> force -> chamber pressure reference -> mass flow, on the plant model, with the
chamber pressure taken from the joint state's effort (net pressure force); without an
effort, or with ``structure:=pid``, PID on position with a bleed feed-forward. Its output
is mass flow; flow_to_duty turns it into PWM duty.

With ``cylinder:=double`` (the double-acting example, one 3/2 valve per chamber) it runs the
two-valve law (``DoublePositionController``): it reads both chamber pressures from the
joint state (joints ``cap_chamber`` and ``rod_chamber``, gauge pressure [Pa] as position)
and publishes ``cap/valve/flow_command`` and ``rod/valve/flow_command``, one per valve,
each to its own ``flow_to_duty``.

With ``lockstep:=true`` (the lockstep simulation, ``valve_lockstep_sim``) there is no timer:
every joint state of a new tick is answered at once with a flow command stamped with the
joint state's stamp, and a goal is acknowledged at once on ``cylinder/position_setpoint``.
"""
from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from valve_msgs.msg import FlowCommand

from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DIAGNOSTICS,
                                       TOPIC_JOINT_STATES, TOPIC_POSITION_GOAL,
                                       TOPIC_POSITION_SETPOINT)
from valve_model_pkg.interface.ros import DIAGNOSTICS_QOS, JOINT_STATES_QOS
from valve_model_pkg.nodes.common import (COMMAND_QOS, TOPIC_FLOW_COMMAND, DiagnosticLevel,
                                          declare_bool, declare_float, declare_string,
                                          key_values, run_node)
from valve_model_pkg.nodes.inputs import InputGuard
from valve_model_pkg.pneumatics.controller import (ControllerGains, DoublePositionController,
                                                   PositionController)
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
                                     'Add the model-based feed-forward (holding pressure, '
                                     'bleed)'),
            structure=declare_string(self, 'structure', g.structure,
                                     'Control law: cascade (position -> pressure -> flow, '
                                     'uses the measured chamber pressure) or pid (flow PID)'),
            stiffness_n_per_m=declare_float(self, 'stiffness_n_per_m', g.stiffness_n_per_m,
                                            'Cascade: force per metre of error [N/m]',
                                            0.0, 1e6),
            integral_n_per_m_s=declare_float(self, 'integral_n_per_m_s', g.integral_n_per_m_s,
                                             'Cascade: integral gain [N/(m s)]', 0.0, 1e7),
            damping_n_s_per_m=declare_float(self, 'damping_n_s_per_m', g.damping_n_s_per_m,
                                            'Cascade: velocity damping [N s/m]', 0.0, 1e5),
            pressure_time_constant_s=declare_float(
                self, 'pressure_time_constant_s', g.pressure_time_constant_s,
                'Cascade: time constant of the pressure loop [s]', 1e-3, 10.0),
            integral_zone_m=declare_float(self, 'integral_zone_m', g.integral_zone_m,
                                          'Cascade: integrate only within this error [m]',
                                          0.0, 2.0))
        # The feedforward needs the plant's model: the same parameters as the cylinder's.
        defaults = CylinderParameters()
        plant = {name: declare_float(self, f'plant.{name}', getattr(defaults, name), text,
                                     low, high)
                 for name, (text, low, high) in PARAMETER_INFO.items()}
        kind = declare_string(
            self, 'cylinder', 'single',
            'single: one valve, valve/flow_command; double: double-acting cylinder, one 3/2 '
            'valve per chamber, cap/valve/flow_command and rod/valve/flow_command')
        if kind not in ('single', 'double'):
            raise ValueError(f'parameter \'cylinder\' = {kind!r}: expected single or double')
        self._double = kind == 'double'
        supply = declare_float(self, 'supply_pressure_pa', 400_000.0,
                               'Supply pressure, gauge [Pa] (double: the pressure split)',
                               0.0, 1.0e6)
        if self._double:
            # the two-valve law has its own default gains (stiffer: both chambers push)
            self._controller = DoublePositionController(
                None, CylinderParameters(**plant), supply_pressure_pa=supply)
        else:
            self._controller = PositionController(gains, CylinderParameters(**plant))
        self._chambers: dict[str, float] = {}   # double: absolute chamber pressures [Pa]
        self._rate_hz = declare_float(self, 'rate_hz', 200.0, 'Control rate [Hz]', 1.0, 2000.0)
        self._lockstep = declare_bool(
            self, 'lockstep', False,
            'Simulation in lockstep: answer every joint state of a new tick at once with a '
            'flow command stamped with that tick (no timer); see valve_lockstep_sim')
        #: In lockstep every answer is a message callback (nodes/common.make_executor).
        self.message_driven = self._lockstep
        self._last_tick_ns = -1
        self._setpoint_m = declare_float(self, 'initial_setpoint_m', 0.0,
                                         'Setpoint until a goal arrives [m]', 0.0, 2.0)
        self._stroke_m = plant['stroke_m']
        self._position_m: float | None = None
        self._velocity_m_s = 0.0
        self._pressure_pa: float | None = None  # chamber, absolute; from the joint's effort
        self._area_m2 = CylinderParameters(**plant).piston_area_m2
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the diagnostics summary [s]', 0.05, 60.0)
        self._inputs = InputGuard(self.get_logger())
        self._sequence = 0  # of the next flow command
        names = DoublePositionController.names if self._double else ('',)
        self._flow_pubs = {n: self.create_publisher(
            FlowCommand, f'{n}/{TOPIC_FLOW_COMMAND}' if n else TOPIC_FLOW_COMMAND, COMMAND_QOS)
            for n in names}
        self._last_flows: dict[str, FlowCommand] = {}
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS,
                                               DIAGNOSTICS_QOS)
        self._setpoint_pub = self.create_publisher(Float64, TOPIC_POSITION_SETPOINT, COMMAND_QOS)
        self.create_subscription(JointState, TOPIC_JOINT_STATES, self._on_joint,
                                 JOINT_STATES_QOS)
        self.create_subscription(Float64, TOPIC_POSITION_GOAL, self._on_goal, COMMAND_QOS)
        if not self._lockstep:
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
        # Acknowledge at once: a driver holding the simulation knows the goal is in force.
        self._setpoint_pub.publish(Float64(data=self._setpoint_m))

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
        effort = float(msg.effort[i]) if len(msg.effort) > i else math.nan
        # effort = net pressure force on the piston (the plant's convention): the chamber
        # pressure the cascade's pressure loop needs; without it the flow PID runs.
        self._pressure_pa = ATMOSPHERIC_PRESSURE_PA + effort / self._area_m2 \
            if math.isfinite(effort) else None
        if self._double:
            names = list(msg.name)
            for n in DoublePositionController.names:
                j = names.index(f'{n}_chamber') if f'{n}_chamber' in names else -1
                value = float(msg.position[j]) if 0 <= j < len(msg.position) else math.nan
                if math.isfinite(value):
                    self._chambers[n] = ATMOSPHERIC_PRESSURE_PA + value
        if self._lockstep:
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if stamp_ns > self._last_tick_ns:
                self._last_tick_ns = stamp_ns
                self._on_tick(msg.header.stamp)
            elif stamp_ns == self._last_tick_ns and self._last_flows:
                # The simulation sent the tick again: our answer was lost (e.g. published
                # before discovery matched). Send the same answer again; the control law
                # runs once per tick, so its state does not depend on resends.
                for n, flow in self._last_flows.items():
                    flow.sequence = self._sequence
                    self._flow_pubs[n].publish(flow)
                self._sequence += 1

    def _on_tick(self, stamp: object | None = None) -> None:
        setpoint = Float64(data=self._setpoint_m)
        self._setpoint_pub.publish(setpoint)
        if self._position_m is None:
            return  # no feedback yet: command nothing rather than guess
        if self._double:
            if len(self._chambers) < 2:
                return  # no chamber pressures yet: command nothing rather than guess
            flows = self._controller.update(self._setpoint_m, self._position_m,
                                            self._velocity_m_s, 1.0 / self._rate_hz,
                                            self._chambers['cap'], self._chambers['rod'])
        else:
            flows = {'': self._controller.update(self._setpoint_m, self._position_m,
                                                 self._velocity_m_s, 1.0 / self._rate_hz,
                                                 self._pressure_pa)}
        stamp = stamp if stamp is not None else self.get_clock().now().to_msg()
        for n, flow in flows.items():
            msg = FlowCommand()
            msg.header.stamp = stamp
            msg.header.frame_id = self.get_fully_qualified_name()
            msg.sequence = self._sequence
            msg.mass_flow = flow
            self._flow_pubs[n].publish(msg)
            self._last_flows[n] = msg
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
