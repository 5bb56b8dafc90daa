"""valve_can_driver: lifecycle node that puts a CAN-connected valve controller on ROS 2.

Same topics and types as ``valve_simulator`` (controllers and recordings cannot tell them
apart):

- subscribes ``valve/duty_command`` (valve_msgs/DutyCommand);
- subscribes ``valve/supply_pressure``, ``valve/output_pressure`` (sensor_msgs/FluidPressure,
  absolute Pa); until one arrives the parameters ``supply_pressure_pa`` /
  ``output_pressure_pa`` (gauge) are used; the driver forwards them to the controller;
- publishes ``valve/state`` (valve_msgs/ValveState, ``source = SOURCE_CAN``), one message per
  valid telemetry frame (1 kHz with the default controller), while active; the writer keeps
  its last states for a reader that asks for them (``STATE_DURABLE_QOS``: the lockstep
  simulation, which must not lose one because the match came late);
- publishes ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): four statuses (CAN bus,
  telemetry, commands, controller) every ``diagnostics_period_s`` and at once on every
  level change (from configure to cleanup), named ``<namespace/node name> node <id>:
  <status>`` (e.g. ``left/valve_can_driver node 3: telemetry``), so two drivers never
  share a name;
- serves ``~/clear_faults`` (std_srvs/Trigger) and answers what was cleared and what is
  still active: protocol ``suite`` sends ``ClearFaults`` once and reads the controller's
  heartbeat after it (success = no latched fault left); ``canopen`` resets the
  device's communication (NMT) and reads its error register once it is set up again;
  ``j1939`` asks the valve for DM11 and reads its next DM1; ``dbc`` refuses (success
  false, the message says why).
- parameter ``drive_mode`` (``normal`` | ``bench``, checked at start-up and on every set;
  settable at run time, the change is logged): sent as ``ValveCommand.DriveMode`` in every
  command frame; the controller's ``ValveDrive`` report (mode in force, holding-current and
  capacitor set points, supply voltage) is published in the controller status of
  ``/diagnostics``. Stops (duty 0, deactivate, watchdog, shutdown) act at once in either
  mode. The device protocols carry no drive mode: anything but ``normal`` is refused
  with them (at start-up, and when set).

Duty commands are counted (received, rejected, on the bus, superseded, lost by their
``sequence`` per ``header.frame_id``, stale: older than ``stale_command_s`` from their
``header.stamp`` when their frame goes out). The subscription's depth
(``COMMAND_QUEUE_DEPTH``) holds 50 ms of commands at the documented 1 kHz. The command
watchdog (``command_timeout_s``) counts the node's time: with ``use_sim_time`` simulation
time, so a simulation held in lockstep (no commands because no time passes) does not
trip it.

Each ``valve/state`` is stamped with the time its telemetry frame was on the bus (the
frame's timestamp when it is the wall clock's: the interface's receive time, or the
sender's on ``tcp_loopback``), not with the moment the node got to it; with
``use_sim_time`` the frame's timestamp when it is the simulation clock's (the emulator on
the simulation clock stamps each frame with its model instant), else the node's clock.

Lifecycle: configure opens the bus and starts receiving; activate starts sending commands
(duty 0 until a command arrives); deactivate commands duty 0 with the output disabled and
stops sending; cleanup and shutdown close the bus (safe twice). ``autostart:=true``
configures and activates at start-up (for the demo).

All bus I/O runs on the driver core's threads (:mod:`valve_driver_pkg.driver.core`);
callbacks here only hand values over. The parameters, their defaults and ranges are the
fields of :class:`~valve_driver_pkg.driver.config.DriverConfig` and :class:`NodeOptions`.
The core's :mod:`logging` records (logger ``valve_driver_pkg``) go to this node's logger
and so to ``/rosout``.
"""
from __future__ import annotations

import dataclasses
import gc
import logging
import math
import sys
import threading
from dataclasses import dataclass

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleState, Node, TransitionCallbackReturn
from rclpy.task import Future
from rclpy.time import Time
from sensor_msgs.msg import FluidPressure
from std_srvs.srv import Trigger
from valve_msgs.msg import DutyCommand, ValveState

from valve_driver_pkg.devices.settings import PROTOCOL_SETTINGS, build_protocol
from valve_driver_pkg.driver.config import DriverConfig, check_protocol_settings, setting
from valve_driver_pkg.driver.core import CanDriverCore
from valve_driver_pkg.errors import ValveDriverError
from valve_model_pkg.interface import (TOPIC_DIAGNOSTICS, TOPIC_DUTY_COMMAND,
                                       TOPIC_OUTPUT_PRESSURE, TOPIC_STATE,
                                       TOPIC_SUPPLY_PRESSURE, gauge_from_absolute)
from valve_model_pkg.interface.ros import (COMMAND_QOS, PRESSURE_QOS, STATE_DURABLE_QOS,
                                           forward_logging, state_message)
from valve_model_pkg.model.sample import ValveSample

__all__ = ['CanDriverNode', 'NodeOptions', 'main']

#: The logger of every ROS-free module of this package (driver core, protocol, bus).
CORE_LOGGER = 'valve_driver_pkg'


@dataclass(frozen=True)
class NodeOptions:
    """The node's own parameters (the driver's are :class:`DriverConfig`)."""

    params_file: str = setting('', 'Valve parameter YAML for the orifice equation; empty = '
                               'the model\'s default config/valve.yaml')
    duty_map_file: str = setting('', 'Static duty map of the valve (valve_map) for a device '
                                 'that reports no spool position (canopen, j1939): the '
                                 'period-mean position and the flow are derived from the '
                                 'duty in force at pwm_frequency_hz; empty = the suite\'s map')
    valve_name: str = setting('valve', 'Name of the valve, used as header.frame_id')
    diagnostics_period_s: float = setting(1.0, 'Period of the diagnostics summary [s]',
                                          0.05, 60.0)
    autostart: bool = setting(False, 'Configure and activate at start-up')


def _descriptor(field: dataclasses.Field) -> ParameterDescriptor:
    """The ParameterDescriptor of a settings field: type, description, range."""
    meta = field.metadata
    kind = type(field.default)
    descriptor = ParameterDescriptor(description=meta['description'])
    if kind is bool:
        descriptor.type = ParameterType.PARAMETER_BOOL
    elif kind is int:
        low, high = meta['range']
        descriptor.type = ParameterType.PARAMETER_INTEGER
        descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high),
                                                 step=1)]
    elif kind is float:
        low, high = meta['range']
        descriptor.type = ParameterType.PARAMETER_DOUBLE
        descriptor.floating_point_range = [FloatingPointRange(
            from_value=float(low), to_value=float(high), step=0.0)]
    else:
        descriptor.type = ParameterType.PARAMETER_STRING
    return descriptor


class CanDriverNode(Node):
    """Lifecycle node around :class:`~valve_driver_pkg.driver.core.CanDriverCore`."""

    def __init__(self, node_name: str = 'valve_can_driver') -> None:
        super().__init__(node_name)
        for field in dataclasses.fields(DriverConfig) + dataclasses.fields(NodeOptions):
            self.declare_parameter(field.name, field.default, _descriptor(field))
        for prefix, settings in PROTOCOL_SETTINGS.items():
            for field in dataclasses.fields(settings):
                self.declare_parameter(f'{prefix}.{field.name}', field.default,
                                       _descriptor(field))
        self._log_handler = forward_logging(self, CORE_LOGGER)
        self._core: CanDriverCore | None = None
        self._state_pub = None
        self._diag_pub = None
        self._subs: list = []
        self._timers: list = []
        self._sequence = 0
        #: On simulation time the driver is in the lockstep chain: its work is the bus's
        #: frames and message callbacks (nodes/common.make_executor).
        self.message_driven = bool(self.get_parameter('use_sim_time').value)
        self._frame_id = NodeOptions.valve_name
        self._hardware_id = ''
        self._status_prefix = self.get_fully_qualified_name().lstrip('/')
        self._clear_service = None
        # A bad drive_mode or protocol, or a drive mode the protocol cannot carry, refuses
        # the start (exit 2) with the value and the choices.
        check_protocol_settings(self.get_parameter('protocol').value,
                                self.get_parameter('drive_mode').value)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

    def _read(self, settings: type, prefix: str = '') -> object:
        """The typed snapshot of a settings dataclass from the parameters."""
        return settings(**{f.name: self.get_parameter(prefix + f.name).value
                           for f in dataclasses.fields(settings)})

    def _make_core(self, config: DriverConfig, options: NodeOptions) -> CanDriverCore:
        """The suite's core, or the device core with the protocol ``config.protocol``."""
        from valve_driver_pkg.driver.receive import mass_flow_function
        from valve_model_pkg.model import load_parameters
        params = load_parameters(options.params_file or None)
        mass_flow = mass_flow_function(params)
        if config.protocol == 'suite':
            return CanDriverCore(config, mass_flow=mass_flow, on_state=self._publish_state,
                                 on_diagnostics_changed=self._publish_diagnostics)
        from valve_driver_pkg.devices.core import DeviceDriverCore
        from valve_driver_pkg.devices.derived import derived_opening_for
        protocol = build_protocol(config, *(self._read(cls, f'{prefix}.')
                                            for prefix, cls in PROTOCOL_SETTINGS.items()))
        derived = derived_opening_for(protocol.measures_position, options.duty_map_file,
                                      params, options.params_file or 'the suite\'s valve.yaml',
                                      config.pwm_frequency_hz)
        return DeviceDriverCore(config, protocol, mass_flow=mass_flow,
                                on_state=self._publish_state,
                                on_diagnostics_changed=self._publish_diagnostics,
                                derived=derived)

    # --- lifecycle ---------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        config: DriverConfig = self._read(DriverConfig)
        options: NodeOptions = self._read(NodeOptions)
        self._frame_id = options.valve_name
        self._hardware_id = config.hardware_id
        self._status_prefix = (f'{self.get_fully_qualified_name().lstrip("/")} '
                               f'node {config.node_id}')
        try:
            core = self._make_core(config, options)
            if config.protocol != 'suite':
                self._status_prefix = (f'{self.get_fully_qualified_name().lstrip("/")} '
                                       f'{core.protocol.label}')
                self._hardware_id = f'{config.interface}:{config.channel} {core.protocol.label}'
            self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
            self._state_pub = self.create_lifecycle_publisher(ValveState, TOPIC_STATE,
                                                              STATE_DURABLE_QOS)
            self._core = core
            if self.get_parameter('use_sim_time').value:
                core.host_command.watchdog_clock = self._ros_time_s
                core.frame_clock = self._ros_time_s
            core.open()
        except (ValveDriverError, OSError, ValueError, ImportError) as err:
            self.get_logger().error(f'configure failed: {err}')
            self._release()
            return TransitionCallbackReturn.FAILURE
        self._subs = [
            self.create_subscription(DutyCommand, TOPIC_DUTY_COMMAND, self._on_duty,
                                     COMMAND_QOS),
            self.create_subscription(FluidPressure, TOPIC_SUPPLY_PRESSURE,
                                     lambda m: self._on_pressure(m, 'supply'), PRESSURE_QOS),
            self.create_subscription(FluidPressure, TOPIC_OUTPUT_PRESSURE,
                                     lambda m: self._on_pressure(m, 'output'), PRESSURE_QOS),
        ]
        self._timers = [self.create_timer(options.diagnostics_period_s,
                                          self._publish_diagnostics)]
        self._clear_service = self.create_service(Trigger, '~/clear_faults',
                                                  self._on_clear_faults)
        what = (f'DBC {core.codec.dbc_path}' if config.protocol == 'suite'
                else f'protocol {config.protocol}')
        self.get_logger().info(f'configured: {self._hardware_id}, {what}')
        self._publish_diagnostics()
        return TransitionCallbackReturn.SUCCESS

    def _ros_time_s(self) -> float:
        """The node's clock [s]: the command watchdog's with ``use_sim_time``."""
        return self.get_clock().now().nanoseconds * 1e-9

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._core is None or not self._core.is_open:
            self.get_logger().error('activate failed: the bus is not open')
            return TransitionCallbackReturn.FAILURE
        # The state publisher first, then the commands: a controller answers the first
        # command frame with telemetry, and a state published by an inactive lifecycle
        # publisher is dropped (the CAN lockstep start handshake counts on that first one).
        result = super().on_activate(state)
        if result != TransitionCallbackReturn.SUCCESS:
            return result
        self._core.activate()
        self.get_logger().info('active: sending commands (duty 0 until a command arrives)')
        return result

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

    def destroy_node(self) -> None:
        """Stop forwarding the core's log records, then destroy the node."""
        logging.getLogger(CORE_LOGGER).removeHandler(self._log_handler)
        super().destroy_node()

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
        if self._clear_service is not None:
            self.destroy_service(self._clear_service)
            self._clear_service = None
        if self._state_pub is not None:
            self.destroy_lifecycle_publisher(self._state_pub)
            self._state_pub = None
        if self._diag_pub is not None:
            self.destroy_publisher(self._diag_pub)
            self._diag_pub = None

    # --- parameters --------------------------------------------------------------------------
    def _check_parameters(self, parameters: list) -> SetParametersResult:
        """Refuse a protocol or drive_mode that is not one, or a drive mode the protocol
        cannot carry (the others: as declared)."""
        values = {p.name: p.value for p in parameters if p.name in ('protocol', 'drive_mode')}
        if not values:
            return SetParametersResult(successful=True)
        try:
            check_protocol_settings(
                values.get('protocol', self.get_parameter('protocol').value),
                values.get('drive_mode', self.get_parameter('drive_mode').value))
        except ValueError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list) -> None:
        """drive_mode acts at once (the next ValveCommand); the others at configure."""
        for param in parameters:
            if param.name != 'drive_mode':
                continue
            core = self._core
            if core is not None:
                core.set_drive_mode(param.value)   # logs the change
            else:
                self.get_logger().info(f'drive_mode {param.value}: sent once configured')

    # --- inputs ------------------------------------------------------------------------------
    def _on_duty(self, msg: DutyCommand) -> None:
        core = self._core
        if core is None or not core.is_active:
            self.get_logger().warning('duty command ignored: driver not active',
                                      throttle_duration_sec=5.0)
            return
        sequence = getattr(msg, 'sequence', None)   # DutyCommand.sequence (per publisher)
        result = core.set_command(msg.duty, msg.pwm_frequency, age_s=self._age_s(msg.header),
                                  sequence=sequence, source=msg.header.frame_id)
        if result.message:
            self.get_logger().warning(result.message, throttle_duration_sec=1.0)

    def _age_s(self, header) -> float:
        """Age of a message from its header stamp [s]; 0 without a stamp (age from receipt)."""
        stamp = header.stamp
        if stamp.sec == 0 and stamp.nanosec == 0:
            return 0.0
        age = (self.get_clock().now().nanoseconds - (stamp.sec * 10**9 + stamp.nanosec)) * 1e-9
        return age if 0.0 <= age < 3600.0 else 0.0   # clocks apart: count from receipt

    async def _on_clear_faults(self, request: Trigger.Request,
                               response: Trigger.Response) -> Trigger.Response:
        """~/clear_faults: the wait for the controller's answer (up to one heartbeat,
        100 ms) runs on a helper thread, so duty commands keep flowing meanwhile."""
        core = self._core
        if core is None:
            response.success, response.message = False, 'not configured: no bus'
            return response
        done = Future(executor=self.executor)
        done.add_done_callback(lambda _: None)   # its scheduling wakes the executor

        def work() -> None:
            try:
                done.set_result(core.clear_faults())
            except Exception as err:   # noqa: BLE001 - handed to the service's caller
                done.set_exception(err)

        threading.Thread(target=work, name='valve_clear_faults', daemon=True).start()
        result = await done
        response.success, response.message = result.success, result.message
        self._publish_diagnostics()
        return response

    def _on_pressure(self, msg: FluidPressure, port: str) -> None:
        core = self._core
        if core is None:
            return
        gauge = gauge_from_absolute(msg.fluid_pressure)
        ok = core.set_pressures(**{f'{port}_pa': gauge}) if msg.fluid_pressure >= 0.0 else False
        if not ok:
            self.get_logger().warning(f'{port} pressure rejected: {msg.fluid_pressure!r} Pa '
                                      'absolute is not a finite non-negative pressure',
                                      throttle_duration_sec=1.0)

    # --- outputs (called on the driver core's threads) ---------------------------------------
    def _publish_state(self, sample: ValveSample) -> None:
        pub = self._state_pub
        if pub is None:
            return
        # A state is stamped when its frame was on the bus (the sample's time, on the node's
        # clock): the receive thread's lateness, which bunches frames under load, stays out
        # of the time axis.
        if math.isfinite(sample.t_s) and sample.t_s > 0.0:
            stamp = Time(nanoseconds=int(round(sample.t_s * 1e9))).to_msg()
        else:
            stamp = self.get_clock().now().to_msg()
        # samples the controller took and the bus lost count in the sequence: a reader
        # then knows the means cover one telemetry period, not the gap
        self._sequence += sample.samples_lost_before
        msg = state_message(sample, stamp, self._frame_id, self._sequence,
                            ValveState.SOURCE_CAN)
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
                                      name=f'{self._status_prefix}: {report.name}',
                                      message=report.message, hardware_id=self._hardware_id)
            status.values = [KeyValue(key=k, value=_text(v)) for k, v in report.values.items()]
            array.status.append(status)
        self._publish(pub, array)


def _text(value: object) -> str:
    return f'{value:.6g}' if isinstance(value, float) else str(value)


def main(args: list[str] | None = None) -> None:
    """Run the driver until Ctrl-C, SIGTERM or an external shutdown.

    ``--help`` prints the parameters and exits 0 (the node is built, never configured: no
    bus is opened). Exit codes: 0 normal end (also on SIGINT/SIGTERM), 2 refused start-up
    input (a parameter outside its range; with autostart, a configuration the driver
    cannot use), 1 a failure inside.
    """
    from valve_model_pkg.nodes.common import (EXIT_FAILURE, EXIT_REFUSED, STARTUP_ERRORS,
                                              StartupRefused, help_requested,
                                              init_with_signal_handling, print_node_help,
                                              spin_until_stopped)
    if help_requested(args):
        sys.exit(print_node_help(CanDriverNode, 'valve_can_driver', args))
    # A driver thread waiting for the GIL waits up to the switch interval (5 ms by default),
    # longer than the 1 ms telemetry period the loss detection works with; 0.5 ms keeps the
    # telemetry timeout (2.5 periods) honest.
    sys.setswitchinterval(0.0005)
    stop = init_with_signal_handling(args)  # SIGINT/SIGTERM: exit 0, duty 0 sent first
    node = None
    code = 0
    try:
        try:
            node = CanDriverNode()
        except STARTUP_ERRORS as err:
            raise StartupRefused(f'cannot start: {err}') from None
        if node.get_parameter('autostart').value:
            if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise StartupRefused('autostart: configure failed (see the log above)')
            if node.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise RuntimeError('autostart: activate failed (see the log above)')
        gc.collect()
        gc.freeze()   # start-up objects out of the collector: shorter pauses at 1 kHz
        spin_until_stopped(node, stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except StartupRefused as err:
        rclpy.logging.get_logger('valve_can_driver').fatal(str(err))
        code = EXIT_REFUSED
    except RuntimeError as err:
        rclpy.logging.get_logger('valve_can_driver').fatal(str(err))
        code = EXIT_FAILURE
    finally:
        if node is not None:
            node.close_driver()
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)


if __name__ == '__main__':
    main()
