"""pneumatic_cylinder: the cylinder plant fed by the valve's mass flow, as a ROS 2 node.

- subscribes ``valve/state`` (valve_msgs/ValveState): the valve's spool position and
  supply pressure; the plant evaluates the valve's orifice (eq. 12) at its own chamber
  pressure on every integration step (C7), so the pressure that sets the flow is never
  stale by a message round trip;
- publishes ``valve/output_pressure`` (sensor_msgs/FluidPressure, absolute Pa): the chamber
  pressure is the valve's output pressure, which sets the valve's flow regime (eq. 12);
- publishes ``cylinder/joint_states`` (sensor_msgs/JointState, joint ``piston``): position
  [m], velocity [m/s], effort = net pressure force on the piston [N].

- publishes ``/diagnostics`` once per ``diagnostics_period_s``: valve states used and
  rejected per kind.

The plant (valve_model_pkg.pneumatics.cylinder, equations C1-C7) is advanced with every
valve/state message to that message's stamp, holding the previous opening over the
interval; a gap longer than ``max_advance_per_tick_s`` is integrated only that far.

No message ends the node (docs/safety.md, "Node inputs"): a valve/state whose
spool_position is not finite or lies outside the valve's stroke by more than 10 % of it,
whose supply_pressure is not a finite gauge pressure within [0, 100 bar gauge] absolute, or
whose stamp has ``nanosec >= 10^9`` is rejected with a warning (the first of each kind
always, then at most one per second per kind) and counted; the last valid values stay.
"""
from __future__ import annotations

import dataclasses
import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure, JointState
from valve_msgs.msg import ValveState

from valve_model_pkg.model import load_parameters
from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DIAGNOSTICS,
                                       TOPIC_JOINT_STATES)
from valve_model_pkg.interface.ros import DIAGNOSTICS_QOS, JOINT_STATES_QOS
from valve_model_pkg.nodes.common import (PRESSURE_QOS, STATE_QOS, TOPIC_OUTPUT_PRESSURE,
                                          TOPIC_STATE, DiagnosticLevel, declare_float,
                                          declare_string, key_values, run_node)
from valve_model_pkg.nodes.inputs import InputGuard, gauge_pressure_reason, stamp_reason
from valve_model_pkg.pneumatics.cylinder import (PARAMETER_INFO, Cylinder, CylinderParameters,
                                                 CylinderState)

#: A spool position may lie this fraction of the stroke beyond either end stop [1] (a
#: measured position carries noise); the plant uses it clamped to the stroke.
SPOOL_MARGIN = 0.1


class CylinderNode(Node):
    """Pneumatic cylinder plant driven by the valve's opening from valve/state."""

    def __init__(self) -> None:
        super().__init__('pneumatic_cylinder')
        defaults = CylinderParameters()
        values = {}
        for name, (text, low, high) in PARAMETER_INFO.items():
            values[name] = declare_float(self, name, getattr(defaults, name), text, low, high)
        self._params = dataclasses.replace(defaults, **values)
        pressure_rate = declare_float(self, 'pressure_publish_rate_hz', 200.0,
                                      'Rate of valve/output_pressure [Hz]', 1.0, 5000.0)
        joint_rate = declare_float(self, 'joint_state_rate_hz', 200.0,
                                   'Rate of cylinder/joint_states [Hz] (the plant itself '
                                   'advances with every valve/state)', 1.0, 5000.0)
        y0 = declare_float(self, 'initial_position_m', 0.0, 'Initial piston position [m]',
                           0.0, self._params.stroke_m)
        self._max_advance_s = declare_float(self, 'max_advance_per_tick_s', 0.05,
                                            'Most plant time integrated in one tick [s]',
                                            1e-3, 1.0)
        valve_file = declare_string(
            self, 'valve_params_file', '',
            'Valve parameter YAML, for the valve\'s orifice (empty: the paper\'s values)')
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the diagnostics summary [s]', 0.05, 60.0)
        valve = load_parameters(valve_file or None)
        self._x_max_m = float(valve.stroke_m)
        self._inputs = InputGuard(self.get_logger())
        self._states_used = 0
        self._stamps_backwards = 0
        # The orifice equation is compiled code whose first call loads it (seconds): done
        # here on a throw-away plant, not on the first valve/state, which would stall.
        Cylinder(self._params, CylinderState(position_m=y0), valve).step_with_valve(
            self._params.step_s, 0.0, 0.0)
        self._cylinder = Cylinder(self._params, CylinderState(position_m=y0), valve)
        self._opening_m = 0.0
        self._supply_pa = 0.0
        self._last_stamp_ns: int | None = None
        self._pressure_pub = self.create_publisher(FluidPressure, TOPIC_OUTPUT_PRESSURE,
                                                   PRESSURE_QOS)
        self._joint_pub = self.create_publisher(JointState, TOPIC_JOINT_STATES, JOINT_STATES_QOS)
        self.create_subscription(ValveState, TOPIC_STATE, self._on_valve, STATE_QOS)
        self.create_timer(1.0 / pressure_rate, self._publish_pressure)
        self.create_timer(1.0 / joint_rate, self._publish_joint)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS,
                                               DIAGNOSTICS_QOS)
        self.create_timer(diag_period, self._publish_diagnostics)
        self.get_logger().info(
            f'cylinder: bore {self._params.bore_diameter_m * 1e3:g} mm, stroke '
            f'{self._params.stroke_m * 1e3:g} mm, mass {self._params.moving_mass_kg:g} kg, '
            f'spring {self._params.spring_stiffness_n_per_m:g} N/m')

    def _on_valve(self, msg: ValveState) -> None:
        """Advance the plant to this state's stamp with the previous opening held.

        The plant runs on the valve's own sample times (event-driven): no timer of its own,
        so its coupling to the valve does not depend on how this process is scheduled.
        """
        opening, supply = float(msg.spool_position), float(msg.supply_pressure)
        keep = '; keeping the last valid values'
        if not (math.isfinite(opening) and math.isfinite(supply)):
            self._inputs.reject('valve_state', 'not_finite',
                                f'valve/state spool_position {opening!r} / supply_pressure '
                                f'{supply!r} not finite' + keep)
            return
        margin = SPOOL_MARGIN * self._x_max_m
        if not -margin <= opening <= self._x_max_m + margin:
            self._inputs.reject('valve_state', 'position_out_of_range',
                                f'valve/state spool_position {opening!r} m outside '
                                f'[{-margin:g}, {self._x_max_m + margin:g}] m' + keep)
            return
        reason = gauge_pressure_reason(supply)
        if reason is not None:
            self._inputs.reject('valve_state', 'pressure_out_of_range',
                                f'valve/state supply_pressure: {reason}' + keep)
            return
        reason = stamp_reason(msg.header.stamp)
        if reason is not None:
            self._inputs.reject('valve_state', 'bad_stamp', f'valve/state: {reason}' + keep)
            return
        opening = min(max(opening, 0.0), self._x_max_m)
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self._last_stamp_ns is not None and stamp_ns > self._last_stamp_ns:
            dt = (stamp_ns - self._last_stamp_ns) * 1e-9
            if dt > self._max_advance_s:
                self.get_logger().warning(
                    f'{dt * 1e3:.1f} ms between valve states; integrating '
                    f'{self._max_advance_s * 1e3:.0f} ms only', throttle_duration_sec=1.0)
                dt = self._max_advance_s
            try:
                self._cylinder.step_with_valve(dt, self._opening_m, self._supply_pa)
            except (ValueError, ArithmeticError) as err:
                # the plant refuses what it cannot integrate: never end the node on it
                self._inputs.reject('valve_state', 'plant_refused',
                                    f'valve/state could not be integrated: {err}' + keep)
                return
        elif self._last_stamp_ns is not None and stamp_ns < self._last_stamp_ns:
            self._stamps_backwards += 1
            self.get_logger().warning('valve/state stamps went backwards; plant time restarts',
                                      throttle_duration_sec=1.0)
        self._last_stamp_ns = stamp_ns
        self._opening_m, self._supply_pa = opening, supply
        self._states_used += 1

    def _publish_diagnostics(self) -> None:
        level, text = DiagnosticLevel.OK, 'integrating the plant'
        if self._inputs.total:
            level = DiagnosticLevel.WARN
            text = f'{self._inputs.total} message(s) rejected; last: {self._inputs.last_reason}'
        state = self._cylinder.state
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: cylinder plant',
                                  message=text, hardware_id='cylinder')
        status.values = key_values(
            valve_states_used=self._states_used, stamps_backwards=self._stamps_backwards,
            rejected_messages=self._inputs.total, **self._inputs.diagnostic_values(),
            position_m=state.position_m, pressure_pa=state.pressure_pa)
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)

    def _publish_joint(self) -> None:
        state = self._cylinder.state
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = ['piston']
        msg.position = [state.position_m]
        msg.velocity = [state.velocity_m_s]
        msg.effort = [(state.pressure_pa - ATMOSPHERIC_PRESSURE_PA)
                      * self._params.piston_area_m2]
        self._joint_pub.publish(msg)

    def _publish_pressure(self) -> None:
        msg = FluidPressure()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = 'cylinder_chamber'
        msg.fluid_pressure = self._cylinder.state.pressure_pa
        self._pressure_pub.publish(msg)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(CylinderNode, 'pneumatic_cylinder', args)


if __name__ == '__main__':
    main()
