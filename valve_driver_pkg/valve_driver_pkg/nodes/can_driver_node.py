"""valve_can_driver: lifecycle node that puts a CAN-connected valve controller on ROS 2.

Same topics and types as ``valve_simulator`` (controllers and recordings cannot tell them
apart):

- subscribes ``valve/duty_command`` (valve_msgs/DutyCommand);
- subscribes ``valve/supply_pressure``, ``valve/output_pressure`` (sensor_msgs/FluidPressure,
  absolute Pa); until one arrives the parameters ``supply_pressure_pa`` /
  ``output_pressure_pa`` (gauge) are used; the driver forwards them to the controller;
- publishes ``valve/state`` (valve_msgs/ValveState, ``source = SOURCE_CAN``), one message per
  valid telemetry frame (1 kHz with the default controller), while active;
- publishes ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): four statuses (CAN bus,
  telemetry, commands, controller) every ``diagnostics_period_s`` and at once on every
  level change (from configure to cleanup).

Lifecycle: configure opens the bus and starts receiving; activate starts sending commands
(duty 0 until a command arrives); deactivate commands duty 0 with the output disabled and
stops sending; cleanup and shutdown close the bus (safe twice). ``autostart:=true``
configures and activates at start-up (for the demo).

All bus I/O runs on the driver core's threads (:mod:`valve_driver_pkg.driver.core`);
callbacks here only hand values over.
"""
from __future__ import annotations

import gc
import sys

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleState, Node, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import FluidPressure
from valve_msgs.msg import DutyCommand, ValveState

from valve_driver_pkg.driver.core import CanDriverCore, DriverConfig, StateSample
from valve_driver_pkg.errors import ValveDriverError

__all__ = ['CanDriverNode', 'main', 'state_message']

# The suite's topic contract (valve_model_pkg.nodes.common holds the same names; they are
# repeated here so the driver does not pull in the simulator's node helpers).
TOPIC_STATE = 'valve/state'
TOPIC_DUTY_COMMAND = 'valve/duty_command'
TOPIC_SUPPLY_PRESSURE = 'valve/supply_pressure'
TOPIC_OUTPUT_PRESSURE = 'valve/output_pressure'
TOPIC_DIAGNOSTICS = '/diagnostics'
ATMOSPHERIC_PRESSURE_PA = 101_325.0
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

_FLOAT_PARAMS = (
    # name, default, description, low, high
    ('command_rate_hz', 100.0, 'ValveCommand refresh rate [Hz] (also sent on every command)',
     1.0, 1000.0),
    ('command_timeout_s', 0.5, 'Watchdog: no duty command for this long commands duty 0 [s]; '
     '0 = off', 0.0, 60.0),
    ('telemetry_rate_hz', 1000.0, 'Expected ValveTelemetry rate of the controller [Hz]',
     1.0, 10000.0),
    ('telemetry_timeout_periods', 2.5, 'Telemetry is lost (ERROR) this many telemetry periods '
     'after the last valid frame', 1.0, 1000.0),
    ('status_timeout_s', 0.35, 'ValveStatus heartbeat missing this long is an ERROR [s]',
     0.01, 60.0),
    ('pressure_rate_hz', 10.0, 'ValvePressure refresh rate [Hz]', 0.1, 1000.0),
    ('fault_hold_s', 1.0, 'A rejected frame or clamped command keeps its WARN this long [s]',
     0.0, 3600.0),
    ('reopen_period_s', 0.5, 'Pause between attempts to reopen a failed bus [s]', 0.01, 60.0),
    ('open_timeout_s', 5.0, 'How long configure waits for the bus (tcp_loopback: the hub) [s]',
     0.0, 120.0),
    ('pwm_frequency_hz', 50.0, 'PWM frequency in force until a command sets one [Hz]',
     0.1, 1000.0),
    ('max_pwm_frequency_hz', 1000.0, 'Commands above this PWM frequency are clamped [Hz]',
     0.1, 1000.0),
    ('supply_pressure_pa', 400_000.0, 'Supply pressure, gauge [Pa], until valve/supply_pressure '
     'is received', 0.0, 1.0e6),
    ('output_pressure_pa', 0.0, 'Output port pressure, gauge [Pa], until valve/output_pressure '
     'is received', -ATMOSPHERIC_PRESSURE_PA, 1.0e6),
    ('diagnostics_period_s', 1.0, 'Period of the diagnostics summary [s]', 0.05, 60.0),
)
_INT_PARAMS = (
    ('bitrate', 500_000, 'CAN bit rate [bit/s] (socketcan: set with ip link instead)',
     10_000, 1_000_000),
    ('node_id', 0, 'Controller node id: frame id = DBC id + node id', 0, 63),
)
_STRING_PARAMS = (
    ('interface', 'socketcan', 'python-can interface (socketcan, virtual, pcan, ...) or '
     'tcp_loopback (the emulator\'s loopback hub)'),
    ('channel', 'can0', 'Channel: can0, a virtual channel name, or 127.0.0.1:PORT'),
    ('dbc_path', '', 'DBC file of the protocol; empty = the one shipped with the package'),
    ('params_file', '', 'Valve parameter YAML for the orifice equation; empty = the model\'s '
     'default config/valve.yaml'),
    ('valve_name', 'valve', 'Name of the valve, used as header.frame_id'),
)


class CanDriverNode(Node):
    """Lifecycle node around :class:`~valve_driver_pkg.driver.core.CanDriverCore`."""

    def __init__(self, node_name: str = 'valve_can_driver') -> None:
        super().__init__(node_name)
        for name, default, text, low, high in _FLOAT_PARAMS:
            self.declare_parameter(name, float(default), ParameterDescriptor(
                description=text, type=ParameterType.PARAMETER_DOUBLE,
                floating_point_range=[FloatingPointRange(from_value=float(low),
                                                         to_value=float(high), step=0.0)]))
        for name, default, text, low, high in _INT_PARAMS:
            self.declare_parameter(name, int(default), ParameterDescriptor(
                description=text, type=ParameterType.PARAMETER_INTEGER,
                integer_range=[IntegerRange(from_value=low, to_value=high, step=1)]))
        for name, default, text in _STRING_PARAMS:
            self.declare_parameter(name, default, ParameterDescriptor(
                description=text, type=ParameterType.PARAMETER_STRING))
        self.declare_parameter('autostart', False, ParameterDescriptor(
            description='Configure and activate at start-up', type=ParameterType.PARAMETER_BOOL))
        self._core: CanDriverCore | None = None
        self._state_pub = None
        self._diag_pub = None
        self._subs: list = []
        self._timers: list = []
        self._sequence = 0
        self._frame_id = 'valve'
        self._hardware_id = ''

    # --- lifecycle ---------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        p = {name: self.get_parameter(name).value
             for name in [n for n, *_ in _FLOAT_PARAMS + _INT_PARAMS + _STRING_PARAMS]}
        config = DriverConfig(
            interface=p['interface'], channel=p['channel'], bitrate=p['bitrate'],
            node_id=p['node_id'], dbc_path=p['dbc_path'], command_rate_hz=p['command_rate_hz'],
            command_timeout_s=p['command_timeout_s'],
            telemetry_period_s=1.0 / p['telemetry_rate_hz'],
            telemetry_timeout_periods=p['telemetry_timeout_periods'],
            status_timeout_s=p['status_timeout_s'], pressure_rate_hz=p['pressure_rate_hz'],
            fault_hold_s=p['fault_hold_s'], reopen_period_s=p['reopen_period_s'],
            open_timeout_s=p['open_timeout_s'], pwm_frequency_hz=p['pwm_frequency_hz'],
            max_pwm_frequency_hz=p['max_pwm_frequency_hz'])
        self._frame_id = p['valve_name']
        self._hardware_id = f'{config.interface}:{config.channel} node {config.node_id}'
        try:
            mass_flow = _mass_flow_function(p['params_file'])
            core = CanDriverCore(config, mass_flow=mass_flow, on_state=self._publish_state,
                                 on_diagnostics_changed=self._publish_diagnostics,
                                 supply_pressure_pa=p['supply_pressure_pa'],
                                 output_pressure_pa=p['output_pressure_pa'])
            self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
            self._state_pub = self.create_lifecycle_publisher(ValveState, TOPIC_STATE,
                                                              STATE_QOS)
            self._core = core
            core.open()
        except (ValveDriverError, OSError, ValueError, ImportError) as err:
            self.get_logger().error(f'configure failed: {err}')
            self._release()
            return TransitionCallbackReturn.FAILURE
        self._subs = [
            self.create_subscription(DutyCommand, TOPIC_DUTY_COMMAND, self._on_duty,
                                     COMMAND_QOS),
            self.create_subscription(FluidPressure, TOPIC_SUPPLY_PRESSURE,
                                     lambda m: self._on_pressure(m, 'supply'), COMMAND_QOS),
            self.create_subscription(FluidPressure, TOPIC_OUTPUT_PRESSURE,
                                     lambda m: self._on_pressure(m, 'output'), COMMAND_QOS),
        ]
        self._timers = [self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics)]
        self.get_logger().info(f'configured: {self._hardware_id}, DBC {core.codec.dbc_path}')
        self._publish_diagnostics()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._core is None or not self._core.is_open:
            self.get_logger().error('activate failed: the bus is not open')
            return TransitionCallbackReturn.FAILURE
        self._core.activate()
        self.get_logger().info('active: sending commands (duty 0 until a command arrives)')
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._core is not None and not self._core.deactivate():
            self.get_logger().warning('deactivate: the duty-0 frame could not be confirmed sent')
        self.get_logger().info('inactive: valve commanded closed, not sending')
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._core is not None and self._core.is_active:
            self._core.deactivate()
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.get_logger().error('error in a transition: closing the bus')
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def close_driver(self) -> None:
        """Command duty 0 if active, then close the bus (process exit, e.g. Ctrl-C)."""
        if self._core is not None and self._core.is_active:
            self._core.deactivate()
        self._release()

    def _release(self) -> None:
        """Close the bus and drop the ROS entities; safe to call more than once."""
        core, self._core = self._core, None
        if core is not None:
            core.close()
        for timer in self._timers:
            self.destroy_timer(timer)
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._timers, self._subs = [], []
        if self._state_pub is not None:
            self.destroy_lifecycle_publisher(self._state_pub)
            self._state_pub = None
        if self._diag_pub is not None:
            self.destroy_publisher(self._diag_pub)
            self._diag_pub = None

    # --- inputs ------------------------------------------------------------------------------
    def _on_duty(self, msg: DutyCommand) -> None:
        core = self._core
        if core is None or not core.is_active:
            self.get_logger().warning('duty command ignored: driver not active',
                                      throttle_duration_sec=5.0)
            return
        result = core.set_command(msg.duty, msg.pwm_frequency)
        if result.message:
            self.get_logger().warning(result.message, throttle_duration_sec=1.0)

    def _on_pressure(self, msg: FluidPressure, port: str) -> None:
        core = self._core
        if core is None:
            return
        gauge = float(msg.fluid_pressure) - ATMOSPHERIC_PRESSURE_PA
        ok = core.set_pressures(**{f'{port}_pa': gauge}) if msg.fluid_pressure >= 0.0 else False
        if not ok:
            self.get_logger().warning(f'{port} pressure rejected: {msg.fluid_pressure!r} Pa '
                                      'absolute is not a finite non-negative pressure',
                                      throttle_duration_sec=1.0)

    # --- outputs (called on the driver core's threads) ---------------------------------------
    def _publish_state(self, s: StateSample) -> None:
        pub = self._state_pub
        if pub is None:
            return
        msg = state_message(s, self.get_clock().now().to_msg(), self._frame_id,
                            self._sequence)
        self._sequence += 1
        self._publish(pub, msg)

    def _publish(self, pub, msg) -> None:
        """Publish from a driver thread; quiet once rclpy is shutting down (Ctrl-C)."""
        try:
            pub.publish(msg)
        except Exception:   # noqa: BLE001 - rclpy raises RCLError from its private module
            if self.context.ok():
                raise

    def _publish_diagnostics(self) -> None:
        core, pub = self._core, self._diag_pub
        if core is None or pub is None:
            return
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        for report in core.report():
            status = DiagnosticStatus(level=bytes([int(report.level)]),
                                      name=f'{self.get_name()}: {report.name}',
                                      message=report.message, hardware_id=self._hardware_id)
            status.values = [KeyValue(key=k, value=_text(v)) for k, v in report.values.items()]
            array.status.append(status)
        self._publish(pub, array)


def state_message(s: StateSample, stamp, frame_id: str, sequence: int) -> ValveState:
    """The valve_msgs/ValveState for one driver sample (``stamp``: builtin_interfaces/Time)."""
    msg = ValveState()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.sequence = sequence
    msg.coil_voltage = s.coil_voltage_v
    msg.coil_current = s.coil_current_a
    msg.spool_position = s.spool_position_m
    msg.spool_velocity = s.spool_velocity_m_s
    msg.spool_position_avg = s.position_avg_m
    msg.mass_flow = s.mass_flow_kg_s
    msg.duty = s.duty
    msg.pwm_frequency = s.pwm_frequency_hz
    msg.supply_pressure = s.supply_pressure_pa
    msg.output_pressure = s.output_pressure_pa
    msg.source = ValveState.SOURCE_CAN
    msg.position_measured = s.position_measured
    return msg


def _text(value: object) -> str:
    return f'{value:.6g}' if isinstance(value, float) else str(value)


def _mass_flow_function(params_file: str):
    """eq. (12) from the valve model with the given (or default) parameter set."""
    from valve_model_pkg.model import load_parameters
    from valve_model_pkg.model.orifice import orifice_mass_flow

    params = load_parameters(params_file or None)

    def mass_flow(position_avg_m: float, supply_pa: float, output_pa: float) -> float:
        return float(orifice_mass_flow(position_avg_m, supply_pa, output_pa, params))

    mass_flow(params.stroke_m * 0.5, 400_000.0, 0.0)   # compile (numba) before traffic
    return mass_flow


def main(args: list[str] | None = None) -> None:
    """Run the driver until Ctrl-C or an external shutdown."""
    # A driver thread waiting for the GIL waits up to the switch interval (5 ms by default),
    # longer than the 1 ms telemetry period the loss detection works with; 0.5 ms keeps the
    # telemetry timeout (2.5 periods) honest.
    sys.setswitchinterval(0.0005)
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = CanDriverNode()
        if node.get_parameter('autostart').value:
            if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise RuntimeError('autostart: configure failed (see the log above)')
            if node.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise RuntimeError('autostart: activate failed (see the log above)')
        gc.collect()
        gc.freeze()   # start-up objects out of the collector: shorter pauses at 1 kHz
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError as err:
        rclpy.logging.get_logger('valve_can_driver').fatal(str(err))
        code = 1
    finally:
        if node is not None:
            node.close_driver()
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)


if __name__ == '__main__':
    main()
