"""flow_to_duty: turns mass-flow commands into PWM duty commands through the static map.

A higher-level pneumatic controller commands flow instead of duty (paper Section 5). For
each command the node computes the averaged opening that the orifice equation (eq. 12,
choked or subsonic by the ratio of the absolute pressures) needs at the present supply and
output pressures, inverts the static duty map at the supply pressure (interpolating
between the map's pressures) and publishes the duty with its PWM frequency.

Topics (relative to the node's namespace):

- subscribes ``valve/flow_command`` (valve_msgs/FlowCommand, kg/s);
- subscribes ``valve/supply_pressure``, ``valve/output_pressure`` (sensor_msgs/FluidPressure,
  ABSOLUTE Pa as sensor_msgs defines it); until one arrives the parameters (gauge) are used;
- publishes ``valve/duty_command`` (valve_msgs/DutyCommand) and
  ``valve/flow_to_duty_status`` (valve_msgs/FlowToDutyStatus) for every command answered;
- publishes ``/diagnostics`` once per ``diagnostics_period_s``.

Rules (details in docs/maps.md):

- beyond reach: duty 1 (STATUS_SATURATED_HIGH); zero flow: duty 0 (STATUS_SATURATED_LOW);
  no forward pressure difference: duty 0 (STATUS_NO_PRESSURE);
- dead band: a positive flow below what the first opening duty delivers is never given a
  duty that drives the coil without opening the valve: below ``dead_band_zero_fraction`` of
  that flow it gets duty 0 (STATUS_SATURATED_LOW), else the opening duty
  (STATUS_DEAD_BAND_LIFTED);
- NaN, infinite, negative or implausibly large (above ``MAX_FLOW_COMMAND_KG_S``) commands
  are rejected with a warning (STATUS_REJECTED) and the last valid command stays in force;
  so are pressures outside [0, 100 bar gauge] absolute (docs/safety.md, "Node inputs"). The
  first warning of each kind always appears, then at most one per second per kind; every
  rejection is counted per kind in the diagnostics (``rejected_<topic>_<kind>``);
- flow commands are counted by their ``sequence`` per publisher (``header.frame_id``):
  ``commands`` received, ``rejected``, ``commands_lost`` (sequence gaps); the duty commands
  sent carry this node's own sequence and its fully qualified name as ``frame_id``;
- when the pressures change, the command in force is re-evaluated at most every
  ``republish_period_s`` and a new duty is published if it changed;
- the map file must exist, be a valid duty map, contain ``pwm_frequency_hz`` and be made
  for the valve parameter set in force (``params_file``), else the node refuses to start
  (exit code 1, naming the file and the reason);
- with ``lockstep:=true`` (the lockstep simulation, ``valve_lockstep_sim``): each flow
  command is answered with the output pressure stamped at or after the command's stamp
  (if the command overtook that pressure, the answer waits for it, at most
  ``lockstep_pressure_timeout_s`` of wall time, counted), the duty command carries the
  flow command's stamp (the tick it answers), and nothing is republished on pressure
  changes, so the answer to a tick is the same in every run;
- at run time ``pwm_frequency_hz`` (to another of the map's frequencies),
  ``supply_temperature_k`` and ``dead_band_zero_fraction`` can be changed; the other
  parameters need a restart and changing them is refused.
"""
from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import FluidPressure
from valve_msgs.msg import DutyCommand, FlowCommand, FlowToDutyStatus

from valve_model_pkg.maps import (FlowStatus, FlowToDutyInverter, FlowToDutyResult, MapError,
                                  default_map_path, invalid_flow_reason, load_map)
from valve_model_pkg.model import default_parameters_path, load_parameters
from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ
from valve_model_pkg.interface.ros import DIAGNOSTICS_QOS
from valve_model_pkg.nodes.inputs import (MAX_FLOW_COMMAND_KG_S, InputGuard, SequenceTracker,
                                          pressure_reason, stamp_reason)
from valve_model_pkg.nodes.common import (ATMOSPHERIC_PRESSURE_PA, COMMAND_QOS, PRESSURE_QOS,
                                          TOPIC_DIAGNOSTICS, TOPIC_DUTY_COMMAND,
                                          TOPIC_FLOW_COMMAND, TOPIC_FLOW_STATUS,
                                          TOPIC_OUTPUT_PRESSURE, TOPIC_SUPPLY_PRESSURE,
                                          declare_bool, declare_float, declare_string,
                                          DiagnosticLevel,
                                          gauge_from_absolute, key_values, run_node,
                                          STARTUP_ERRORS)
from valve_model_pkg.errors import StartupRefused

#: A duty change smaller than this is not republished on a pressure change [1].
_DUTY_EPS = 1e-9

# The ROS-free status codes must equal the message constants (a node test checks it too).
assert int(FlowStatus.OK) == FlowToDutyStatus.STATUS_OK
assert int(FlowStatus.SATURATED_HIGH) == FlowToDutyStatus.STATUS_SATURATED_HIGH
assert int(FlowStatus.SATURATED_LOW) == FlowToDutyStatus.STATUS_SATURATED_LOW
assert int(FlowStatus.DEAD_BAND_LIFTED) == FlowToDutyStatus.STATUS_DEAD_BAND_LIFTED
assert int(FlowStatus.REJECTED) == FlowToDutyStatus.STATUS_REJECTED
assert int(FlowStatus.NO_PRESSURE) == FlowToDutyStatus.STATUS_NO_PRESSURE


class FlowToDutyNode(Node):
    """Flow command -> duty command through the inverted static map."""

    def __init__(self) -> None:
        super().__init__('flow_to_duty')
        map_file = declare_string(
            self, 'map_file', '',
            'Static duty map file (JSON, from valve_map); empty = the shipped '
            'config/valve_map.json made for the paper\'s parameters')
        params_file = declare_string(
            self, 'params_file', '',
            'Valve parameter set in force (YAML); the map must have been made for it; '
            'empty = config/valve.yaml')
        pwm_hz = declare_float(self, 'pwm_frequency_hz', 50.0,
                               'Main PWM frequency sent with every duty [Hz]; must be one of '
                               'the map\'s frequencies', 1.0, MAX_PWM_FREQUENCY_HZ)
        self._supply_pa = declare_float(
            self, 'supply_pressure_pa', 400_000.0,
            'Supply pressure, gauge [Pa], used until valve/supply_pressure is received',
            -ATMOSPHERIC_PRESSURE_PA, 1.0e7)
        self._output_pa = declare_float(
            self, 'output_pressure_pa', 0.0,
            'Output port pressure, gauge [Pa], used until valve/output_pressure is received',
            -ATMOSPHERIC_PRESSURE_PA, 1.0e7)
        zero_fraction = declare_float(
            self, 'dead_band_zero_fraction', 0.5,
            'Dead-band rule: a positive flow below this fraction of the smallest flow the '
            'valve delivers (at its first opening duty) is sent as duty 0, otherwise as that '
            'opening duty; 0 = always open, 1 = always close, 0.5 = the nearer flow [1]',
            0.0, 1.0)
        self._republish_s = declare_float(
            self, 'republish_period_s', 0.01,
            'On pressure changes, re-evaluate the command in force at most this often and '
            'publish if the duty changed [s]; 0 = only answer flow commands', 0.0, 10.0)
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the diagnostics summary [s]', 0.05, 60.0)
        self._lockstep = declare_bool(
            self, 'lockstep', False,
            'Simulation in lockstep (valve_lockstep_sim): answer each flow command with the '
            'output pressure stamped at or after its stamp (waiting for it if the command '
            'came first), stamp the duty command with the flow command\'s stamp, and never '
            'republish on pressure changes')
        self._lockstep_timeout_s = declare_float(
            self, 'lockstep_pressure_timeout_s', 1.0,
            'Lockstep: wall time to wait for the matching output pressure before answering '
            'with the latest one (counted) [s]', 0.001, 60.0)
        if self._lockstep:
            self._republish_s = 0.0
        #: In lockstep every answer is a message callback (nodes/common.make_executor).
        self.message_driven = self._lockstep

        self._map_path = map_file or _default_map_or_fail()
        self._params_path = params_file or str(default_parameters_path())
        try:
            dmap = load_map(self._map_path)
            params = load_parameters(self._params_path)
            dmap.check_parameters(params, self._map_path, self._params_path)
        except (MapError, ValueError, OSError) as err:
            raise StartupRefused(f'map file refused: {err}') from err
        try:
            temp_default = float(dmap.parameters['orifice']['supply_temperature_k'])
        except (KeyError, TypeError, ValueError) as err:
            raise StartupRefused(f'map file refused: {self._map_path}: no supply temperature in '
                                 'its parameter set') from err
        self._temperature_k = declare_float(
            self, 'supply_temperature_k', temp_default,
            'Supply air temperature T of eq. (12) [K] (default: the parameter set\'s)',
            150.0, 500.0)
        try:
            self._inverter = FlowToDutyInverter(dmap, pwm_hz,
                                                supply_temperature_k=self._temperature_k,
                                                zero_fraction=zero_fraction,
                                                atmospheric_pressure_pa=ATMOSPHERIC_PRESSURE_PA)
        except KeyError as err:
            raise StartupRefused(f'map file refused: {self._map_path}: {err.args[0]}') from err

        self._map = dmap
        self._zero_fraction = zero_fraction
        if dmap.parameters['valve']['area_a3_m2'] != dmap.parameters['valve']['area_a4_m2']:
            self.get_logger().warning(
                'A_3 != A_4 in this parameter set: the output pressure pushes on the spool, '
                f'but the map was made at {dmap.output_pressure_pa:g} Pa output pressure '
                'only; its duties are off at other output pressures')
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._duty_pub = self.create_publisher(DutyCommand, TOPIC_DUTY_COMMAND, COMMAND_QOS)
        self._status_pub = self.create_publisher(FlowToDutyStatus, TOPIC_FLOW_STATUS,
                                                 COMMAND_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, DIAGNOSTICS_QOS)
        self.create_subscription(FlowCommand, TOPIC_FLOW_COMMAND, self._on_flow, COMMAND_QOS)
        self.create_subscription(FluidPressure, TOPIC_SUPPLY_PRESSURE, self._on_supply,
                                 PRESSURE_QOS)
        self.create_subscription(FluidPressure, TOPIC_OUTPUT_PRESSURE, self._on_output,
                                 PRESSURE_QOS)

        self._flow_in_force: float | None = None
        self._flow_stamp = None                # stamp of the command in force (lockstep)
        self._output_stamp_ns = -1             # stamp of the last output pressure
        self._pending_since: float | None = None  # lockstep: waiting for its pressure
        self._pressure_waits = 0
        self._pressure_wait_timeouts = 0
        self._last_duty: float | None = None
        self._last_status: int | None = None
        self._pressure_dirty = False
        self._commands = 0
        self._rejected = 0
        self._last_reject = ''
        self._bad_pressures = 0
        # Per-kind rejection counts and throttled warnings; the flow command stream
        # counted by its sequence numbers (docs/safety.md, "Node inputs").
        self._inputs = InputGuard(self.get_logger())
        self._flow_commands = SequenceTracker()
        self._duty_sequence = 0
        self._counts = {s: 0 for s in FlowStatus}
        self._max_compute_s = 0.0
        if self._lockstep:
            self.create_timer(0.05, self._check_pending,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        if self._republish_s > 0.0:
            self.create_timer(self._republish_s, self._on_republish)
        self.create_timer(diag_period, self._publish_diagnostics)
        feats = dmap.features(dmap.frequency_index(pwm_hz),
                              _nearest(dmap.supply_pressures_pa, self._supply_pa))
        self.get_logger().info(
            f'map {self._map_path} (sha256 {dmap.parameters_sha256[:12]}, '
            f'{dmap.pwm_frequencies_hz.size} frequencies x {dmap.supply_pressures_pa.size} '
            f'pressures) for {self._params_path}; {pwm_hz:g} Hz, dead band up to '
            f'{feats.dead_band_duty:.0%}, saturation from {feats.saturation_duty:.0%} near '
            f'{self._supply_pa:g} Pa; dead-band zero fraction {zero_fraction:g}')

    # --- parameters -----------------------------------------------------------------------
    _LIVE = ('pwm_frequency_hz', 'supply_temperature_k', 'dead_band_zero_fraction')

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Apply the live parameters (rebuilding the inverter); refuse the others."""
        changes = {}
        for p in params:
            if p.name not in self._LIVE:
                return SetParametersResult(successful=False, reason=(
                    f'{p.name} cannot change while running; restart the node'))
            changes[p.name] = float(p.value)
        freq = changes.get('pwm_frequency_hz', self._inverter.pwm_frequency_hz)
        temp = changes.get('supply_temperature_k', self._temperature_k)
        zero = changes.get('dead_band_zero_fraction', self._zero_fraction)
        try:
            inverter = FlowToDutyInverter(self._map, freq, supply_temperature_k=temp,
                                          zero_fraction=zero,
                                          atmospheric_pressure_pa=ATMOSPHERIC_PRESSURE_PA)
        except (KeyError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err.args[0]))
        self._inverter, self._temperature_k, self._zero_fraction = inverter, temp, zero
        self._pressure_dirty = True      # re-evaluate the command in force
        return SetParametersResult(successful=True)

    # --- inputs ---------------------------------------------------------------------------
    def _on_flow(self, msg: FlowCommand) -> None:
        self._commands += 1
        self._flow_commands.update(msg.header.frame_id, msg.sequence)
        flow = msg.mass_flow
        reason = invalid_flow_reason(flow)
        kind = 'not_finite' if reason is not None and (
            'NaN' in reason or 'infinite' in reason) else 'out_of_range'
        if reason is None and flow > MAX_FLOW_COMMAND_KG_S:
            reason = (f'mass_flow {flow!r} kg/s is above {MAX_FLOW_COMMAND_KG_S:g} kg/s '
                      '(implausible)')
        if reason is None:
            reason = stamp_reason(msg.header.stamp)
            kind = 'bad_stamp'
        if reason is not None:
            self._reject(flow, f'flow command rejected: {reason}; keeping the last valid '
                               f'command ({self._flow_in_force!r} kg/s)', kind)
            return
        self._flow_in_force = float(flow)
        self._flow_stamp = msg.header.stamp
        if self._lockstep and _ns(msg.header.stamp) > self._output_stamp_ns:
            # The command overtook the pressure of its tick: answer when that arrives.
            self._pending_since = time.monotonic()
            self._pressure_waits += 1
            return
        self._pending_since = None
        self._answer(force=True)

    def _pressure_from(self, msg: FluidPressure, port: str) -> float | None:
        absolute = msg.fluid_pressure
        reason = pressure_reason(absolute)
        if reason is None:
            reason = stamp_reason(msg.header.stamp)
        if reason is not None:
            self._bad_pressures += 1
            kind = 'not_finite' if 'not finite' in reason else (
                'bad_stamp' if 'stamp' in reason else 'out_of_range')
            self._inputs.reject(f'{port}_pressure', kind,
                                f'{port} pressure rejected: {reason}; keeping the last valid '
                                'value')
            return None
        return gauge_from_absolute(absolute)

    def _on_supply(self, msg: FluidPressure) -> None:
        gauge = self._pressure_from(msg, 'supply')
        if gauge is not None and gauge != self._supply_pa:
            self._supply_pa = gauge
            self._pressure_dirty = True

    def _on_output(self, msg: FluidPressure) -> None:
        gauge = self._pressure_from(msg, 'output')
        if gauge is not None:
            self._output_stamp_ns = max(self._output_stamp_ns, _ns(msg.header.stamp))
        if gauge is not None and gauge != self._output_pa:
            self._output_pa = gauge
            self._pressure_dirty = True
        if self._pending_since is not None and self._flow_stamp is not None \
                and self._output_stamp_ns >= _ns(self._flow_stamp):
            self._pending_since = None
            self._answer(force=True)

    def _check_pending(self) -> None:
        """Lockstep: answer with the latest pressure if the matching one never came."""
        if self._pending_since is not None \
                and time.monotonic() - self._pending_since > self._lockstep_timeout_s:
            self._pending_since = None
            self._pressure_wait_timeouts += 1
            self.get_logger().warning(
                'lockstep: no output pressure stamped at the flow command\'s tick within '
                f'{self._lockstep_timeout_s:g} s; answered with the latest pressure',
                throttle_duration_sec=1.0)
            self._answer(force=True)

    def _on_republish(self) -> None:
        if self._pressure_dirty and self._flow_in_force is not None:
            self._pressure_dirty = False
            self._answer(force=False)

    # --- answers --------------------------------------------------------------------------
    def _answer(self, force: bool) -> None:
        t0 = time.perf_counter()
        try:
            res = self._inverter.compute(self._flow_in_force, self._supply_pa, self._output_pa)
        except (ValueError, ArithmeticError, TypeError) as err:
            # never crash on a message; say what happened and keep the last duty
            self._reject(self._flow_in_force, f'flow command could not be converted: {err}',
                         'not_convertible')
            return
        self._max_compute_s = max(self._max_compute_s, time.perf_counter() - t0)
        if not force and self._last_duty is not None \
                and abs(res.duty - self._last_duty) <= _DUTY_EPS \
                and int(res.status) == self._last_status:
            return
        now = self.get_clock().now().to_msg()
        if self._lockstep and self._flow_stamp is not None:
            now = self._flow_stamp  # the answer to the tick of that flow command
        cmd = DutyCommand()
        cmd.header.stamp = now
        cmd.header.frame_id = self.get_fully_qualified_name()
        cmd.sequence = self._duty_sequence
        self._duty_sequence += 1
        cmd.duty = float(res.duty)
        cmd.pwm_frequency = float(res.pwm_frequency_hz)
        self._duty_pub.publish(cmd)
        self._last_duty = float(res.duty)
        self._last_status = int(res.status)
        self._counts[res.status] += 1
        self._publish_status(res, now)

    def _reject(self, flow: object, text: str, kind: str) -> None:
        self._rejected += 1
        self._last_reject = text
        self._counts[FlowStatus.REJECTED] += 1
        self._inputs.reject('flow_command', kind, text)
        res = FlowToDutyResult(
            requested_mass_flow=float(flow) if isinstance(flow, (int, float)) else math.nan,
            achievable_mass_flow=math.nan, max_mass_flow=math.nan, position_fraction=math.nan,
            duty=self._last_duty if self._last_duty is not None else 0.0,
            pwm_frequency_hz=self._inverter.pwm_frequency_hz,
            supply_pressure_pa=self._supply_pa, output_pressure_pa=self._output_pa,
            choked=False, status=FlowStatus.REJECTED, message=text)
        self._publish_status(res, self.get_clock().now().to_msg())

    def _publish_status(self, res: FlowToDutyResult, stamp: object) -> None:
        st = FlowToDutyStatus()
        st.header.stamp = stamp
        st.requested_mass_flow = float(res.requested_mass_flow)
        st.achievable_mass_flow = float(res.achievable_mass_flow)
        st.max_mass_flow = float(res.max_mass_flow)
        st.position_fraction = float(res.position_fraction)
        st.duty = float(res.duty)
        st.pwm_frequency = float(res.pwm_frequency_hz)
        st.supply_pressure = float(res.supply_pressure_pa)
        st.output_pressure = float(res.output_pressure_pa)
        st.choked = bool(res.choked)
        st.status = int(res.status)
        st.message = res.message
        self._status_pub.publish(st)

    def _publish_diagnostics(self) -> None:
        level, text = DiagnosticLevel.OK, 'converting flow commands'
        problems = []
        if self._flow_commands.lost:
            problems.append(f'{self._flow_commands.lost} flow command(s) lost (sequence gaps)')
        if self._inputs.total:
            problems.append(f'{self._inputs.total} message(s) rejected; last: '
                            f'{self._inputs.last_reason}')
        if problems:
            level, text = DiagnosticLevel.WARN, '; '.join(problems)
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: flow to duty',
                                  message=text, hardware_id='valve')
        status.values = key_values(
            commands=self._commands, rejected=self._rejected,
            commands_lost=self._flow_commands.lost,
            **self._flow_commands.diagnostic_values('flow_commands'),
            duty_commands_sent=self._duty_sequence,
            rejected_messages=self._inputs.total,
            **self._inputs.diagnostic_values(),
            saturated_high=self._counts[FlowStatus.SATURATED_HIGH],
            saturated_low=self._counts[FlowStatus.SATURATED_LOW],
            dead_band_lifted=self._counts[FlowStatus.DEAD_BAND_LIFTED],
            no_pressure=self._counts[FlowStatus.NO_PRESSURE],
            bad_pressure_messages=self._bad_pressures,
            lockstep=self._lockstep, lockstep_pressure_waits=self._pressure_waits,
            lockstep_pressure_wait_timeouts=self._pressure_wait_timeouts,
            max_compute_s=self._max_compute_s, supply_pressure_pa=self._supply_pa,
            output_pressure_pa=self._output_pa, map_file=self._map_path,
            params_file=self._params_path)
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)
        self._max_compute_s = 0.0


def _default_map_or_fail() -> str:
    try:
        return str(default_map_path())
    except FileNotFoundError as err:
        raise StartupRefused(f'map file refused: {err}') from err


def _ns(stamp: object) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _nearest(values: object, v: float) -> int:
    return min(range(len(values)), key=lambda i: abs(values[i] - v))


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(FlowToDutyNode, 'flow_to_duty', args,
             startup_errors=STARTUP_ERRORS)


if __name__ == '__main__':
    main()
