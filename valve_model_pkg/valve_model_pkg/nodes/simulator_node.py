"""valve_simulator: the nonlinear valve model run in real time as a ROS 2 node.

Topics (names relative to the node's namespace):

- subscribes ``valve/duty_command`` (valve_msgs/DutyCommand): main PWM duty and frequency;
- subscribes ``valve/supply_pressure``, ``valve/output_pressure`` (sensor_msgs/FluidPressure,
  absolute Pa as sensor_msgs defines it); until one arrives the parameters are used;
- publishes ``valve/state`` (valve_msgs/ValveState) at ``publish_rate_hz`` (default 1 kHz);
- publishes ``/diagnostics`` (diagnostic_msgs/DiagnosticArray): once per
  ``diagnostics_period_s`` and at once on every tick that fell behind.

On each tick the model is advanced to the node's clock (ROS time, so ``use_sim_time``
works) and the state at that instant is published, stamped with it. The work per tick is
bounded (``max_advance_per_tick_s``): if the clock jumps further than that (a stalled
process, a jump in simulated time), the model is advanced by the bound, then moved on to
the clock without integrating the gap, and the tick is reported as fallen behind. Time
running backwards (a replayed bag looping) resets the model.

No message ends the node (docs/safety.md, "Node inputs"): a duty command or pressure
outside its range is rejected with a warning (the first of each kind always, then at most
one per second per kind) and counted per kind in the diagnostics (``rejected_<topic>_<kind>``,
total ``rejected_commands``); the last valid value stays. Duty commands are also counted by
their ``sequence`` per publisher (``duty_commands_received``, ``duty_commands_lost``, ...).
"""
from __future__ import annotations

import dataclasses

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import FluidPressure
from valve_msgs.msg import DutyCommand, ValveState

from valve_model_pkg.model import ElectronicsConfig, ValveStepper, default_parameters_path, \
    load_electronics, load_parameters
from valve_model_pkg.model.aot import backend as kernel_backend
from valve_model_pkg.interface.ros import DIAGNOSTICS_QOS, forward_logging, state_message
# The accepted PWM frequencies: one pair for simulator, CAN driver and DBC.
from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ
from valve_model_pkg.nodes.sim_status import valve_summary, valve_values
from valve_model_pkg.nodes.tick_loop import TickLoop
from valve_model_pkg.nodes.inputs import (InputGuard, SequenceTracker, accept_duty_command,
                                          accept_pressure)
from valve_model_pkg.nodes.common import (ATMOSPHERIC_PRESSURE_PA, COMMAND_QOS, PRESSURE_QOS,
                                          STATE_QOS, TOPIC_DIAGNOSTICS,
                                          TOPIC_DUTY_COMMAND, TOPIC_OUTPUT_PRESSURE, TOPIC_STATE,
                                          TOPIC_SUPPLY_PRESSURE, declare_bool, declare_float,
                                          declare_string, DiagnosticLevel, run_node)


def declare_electronics(node: Node) -> tuple[ElectronicsConfig, str]:
    """Declare the drive electronics parameters; return the electronics and a summary.

    ``electronics_file`` (a description YAML, empty: the paper's driver) sets the drive;
    ``current_control`` and ``capacitor`` false switch its peak-and-hold phases and its
    release off. A bad file raises ``ParameterError`` naming the file, line, key and value
    (the node then exits 2).
    """
    path = declare_string(
        node, 'electronics_file', '',
        'Drive electronics description (YAML, docs/model.md "Drive electronics"); empty = '
        "the paper's driver (Sec. 4)")
    current_control = declare_bool(
        node, 'current_control', True,
        'Peak and hold phases of the drive (the paper: boost, then a PI chopper holding '
        '0.5 A); false = the full supply for the whole high phase')
    capacitor = declare_bool(
        node, 'capacitor', True,
        'Release voltage at the falling edge (the paper: the capacitor pulse); false = 0 V')
    base = load_electronics(path) if path else ElectronicsConfig()
    electronics = dataclasses.replace(
        base, current_control=base.current_control and current_control,
        negative_voltage=base.negative_voltage and capacitor)
    text = (f'{path or "the paper driver"}, current control {electronics.current_control}, '
            f'release {electronics.release if electronics.negative_voltage else "off"}')
    return electronics, text


class ValveSimulatorNode(Node):
    """Real-time simulation of one PWM-driven solenoid valve."""

    def __init__(self) -> None:
        super().__init__('valve_simulator')
        params_file = declare_string(
            self, 'params_file', '',
            'Valve parameter set (YAML); empty = the paper\'s Table 1/2 values shipped in '
            'config/valve.yaml')
        self._rate_hz = declare_float(self, 'publish_rate_hz', 1000.0,
                                      'Rate of valve/state messages [Hz]', 1.0, 10000.0)
        duty = declare_float(self, 'duty', 0.0, 'Initial main PWM duty [1]', 0.0, 1.0)
        pwm_hz = declare_float(self, 'pwm_frequency_hz', 50.0,
                               'Initial main PWM frequency [Hz]', MIN_PWM_FREQUENCY_HZ,
                               MAX_PWM_FREQUENCY_HZ)
        supply_pa = declare_float(
            self, 'supply_pressure_pa', 400_000.0,
            'Supply pressure, gauge [Pa], used until valve/supply_pressure is received',
            0.0, 1.0e6)
        output_pa = declare_float(
            self, 'output_pressure_pa', 0.0,
            'Output port pressure, gauge [Pa], used until valve/output_pressure is received',
            -ATMOSPHERIC_PRESSURE_PA, 1.0e6)
        supply_voltage = declare_float(self, 'supply_voltage_v', 24.0,
                                       'Drive supply voltage [V]', 0.0, 60.0)
        electronics, electronics_text = declare_electronics(self)
        self._frame_id = declare_string(self, 'valve_name', 'valve',
                                        'Name of the valve, used as header.frame_id')
        self._max_advance_s = declare_float(
            self, 'max_advance_per_tick_s', 0.05,
            'Most model time integrated in one tick [s]; bounds the work per callback',
            1e-4, 1.0)
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the diagnostics summary [s]', 0.05, 60.0)

        path = params_file or str(default_parameters_path())
        allow_implausible = declare_bool(
            self, 'allow_implausible', False,
            'Accept parameter values outside their plausible ranges, with a warning (values '
            'beyond the numerically safe range are refused anyway)')
        # the loader warns through logging: show it in this node's log and /rosout
        forward_logging(self, 'valve_model_pkg.model.parameters')
        # refuses a bad file naming the file, key and value
        self._params = load_parameters(path, allow_implausible=allow_implausible)
        # Load (or compile) the model's kernel before the clock starts: the first call can
        # take seconds, which would otherwise show as a gap in the published stream.
        warm_up = ValveStepper(self._params, electronics, supply_voltage_v=supply_voltage)
        warm_up.set_command(0.5, 50.0)
        warm_up.advance_to(0.045)
        self._stepper = ValveStepper(self._params, electronics, supply_voltage_v=supply_voltage)
        self._stepper.set_command(duty, pwm_hz)
        self._stepper.set_pressures(supply_pa, output_pa)
        self._params_path = path

        self._state_pub = self.create_publisher(ValveState, TOPIC_STATE, STATE_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, DIAGNOSTICS_QOS)
        self.create_subscription(DutyCommand, TOPIC_DUTY_COMMAND, self._on_duty, COMMAND_QOS)
        self.create_subscription(FluidPressure, TOPIC_SUPPLY_PRESSURE, self._on_supply,
                                 PRESSURE_QOS)
        self.create_subscription(FluidPressure, TOPIC_OUTPUT_PRESSURE, self._on_output,
                                 PRESSURE_QOS)

        self._period_s = 1.0 / self._rate_hz
        # the real-time rules (sample grid, bounded work, clock going backwards)
        self._loop = TickLoop(self._period_s, self._max_advance_s,
                              advance_to=self._stepper.advance_to,
                              publish=self._publish_state,
                              restart=self._restart)
        self._sequence = 0
        # Every message is checked; what is refused is counted per input and kind
        # (docs/safety.md, "Node inputs"), and the command stream by its sequence numbers.
        self._inputs = InputGuard(self.get_logger())
        self._commands = SequenceTracker()
        self.create_timer(self._period_s, self._on_tick)
        self.create_timer(diag_period, self._publish_summary)
        self.get_logger().info(
            f'simulating {path} at {self._rate_hz:g} Hz; duty {duty:g} at {pwm_hz:g} Hz, '
            f'supply {supply_pa:g} Pa gauge, electronics: {electronics_text}')
        # which compiled kernel runs: the ahead-of-time module (no numba in the process)
        # or the numba jit (model/aot.py, docs/model.md)
        self.get_logger().info(f'valve kernel: {kernel_backend().origin}')

    # --- inputs ---------------------------------------------------------------------------
    def _on_duty(self, msg: DutyCommand) -> None:
        """Apply a duty command; refuse (and count) one the valve cannot take (the rules of
        :func:`~valve_model_pkg.nodes.inputs.accept_duty_command`)."""
        self._commands.update(msg.header.frame_id, msg.sequence)
        accepted = accept_duty_command(msg, self._inputs,
                                       lambda: self._stepper.sample().pwm_frequency_hz)
        if accepted is not None:
            self._stepper.set_command(*accepted)

    def _pressure_from(self, msg: FluidPressure, port: str) -> float | None:
        return accept_pressure(msg, self._inputs, port)

    def _on_supply(self, msg: FluidPressure) -> None:
        gauge = self._pressure_from(msg, 'supply')
        if gauge is not None:
            s = self._stepper.sample()
            self._set_pressures('supply', gauge, s.output_pressure_pa)

    def _on_output(self, msg: FluidPressure) -> None:
        gauge = self._pressure_from(msg, 'output')
        if gauge is not None:
            s = self._stepper.sample()
            self._set_pressures('output', s.supply_pressure_pa, gauge)

    def _set_pressures(self, port: str, supply_pa: float, output_pa: float) -> None:
        # The model refuses pressures it cannot simulate (ParameterError, e.g. near a
        # perfect vacuum): a message must never end the node, so that becomes a counted
        # rejection and the last value stays.
        try:
            self._stepper.set_pressures(supply_pa, output_pa)
        except ValueError as err:
            self._inputs.reject(f'{port}_pressure', 'model_refused',
                                f'{port} pressure rejected by the model: {err}; keeping the '
                                'last valid value')

    # --- real-time loop -------------------------------------------------------------------
    def _on_tick(self) -> None:
        """Advance the model to the clock, publishing every sample-grid instant passed.

        The rules are :class:`~valve_model_pkg.nodes.tick_loop.TickLoop`'s; a tick that
        fell behind is reported in diagnostics at once.
        """
        reason = self._loop.tick(self.get_clock().now().nanoseconds)
        if reason:
            self._publish_diagnostics(DiagnosticLevel.WARN, 'fell behind: ' + reason)

    def _restart(self) -> None:
        self.get_logger().warning('clock went backwards; restarting the model')
        self._stepper.reset()

    def _publish_state(self, stamp_ns: int) -> None:
        s = self._stepper.sample()
        stamp = Time(nanoseconds=stamp_ns, clock_type=self.get_clock().clock_type)
        msg = state_message(s, stamp.to_msg(), self._frame_id, self._sequence,
                            ValveState.SOURCE_SIMULATOR)
        self._sequence += 1
        self._state_pub.publish(msg)

    # --- diagnostics ----------------------------------------------------------------------
    def _publish_summary(self) -> None:
        self._loop.close_window()
        self._publish_diagnostics(*valve_summary(self._loop, self._commands, self._inputs))
        self._loop.max_tick_compute_s = 0.0

    def _publish_diagnostics(self, level: int, text: str) -> None:
        s = self._stepper.sample()
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: real-time model',
                                  message=text, hardware_id=self._frame_id)
        status.values = valve_values(self._loop, s, rate_hz=self._rate_hz,
                                     sequence=self._sequence, commands=self._commands,
                                     inputs=self._inputs, params_file=self._params_path)
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(ValveSimulatorNode, 'valve_simulator', args, events_executor=True)


if __name__ == '__main__':
    main()
