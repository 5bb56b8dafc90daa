"""valve_bank_simulator: many valves simulated in real time by one ROS 2 node.

A pneumatic robot or test bench has many valves; one ``valve_simulator`` process per valve
spends most of its CPU and memory around the model (rclpy, the executor, numba), not in it.
This node simulates N valves in one process: every tick advances all of them in one
compiled call (:class:`~valve_model_pkg.model.bank.ValveBank`) and publishes each valve's
state.

Topics, per name ``NAME`` of the parameter ``valve_names`` (relative to the node's
namespace, so ``NAME`` plays the role of ``valve_simulator``'s namespace):

- subscribes ``NAME/valve/duty_command`` (valve_msgs/DutyCommand);
- subscribes ``NAME/valve/supply_pressure``, ``NAME/valve/output_pressure``
  (sensor_msgs/FluidPressure, absolute Pa); until one arrives the parameters are used;
- publishes ``NAME/valve/state`` (valve_msgs/ValveState, ``header.frame_id`` = ``NAME``) at
  ``publish_rate_hz``;
- publishes ``/diagnostics``: one DiagnosticStatus per valve (hardware_id ``NAME``, the
  same keys as ``valve_simulator``), once per ``diagnostics_period_s`` and at once on
  every tick that fell behind.

Message contract, parameters, input checks and the real-time rules (grid of sample
instants, bounded work per tick, clock going backwards) are those of ``valve_simulator``
(:mod:`.simulator_node`); ``valve_name``/``params_file`` become ``valve_names``/
``params_files`` (one file for all valves, or one per valve). A rejected message of one
valve is counted for that valve only.
"""
from __future__ import annotations

import re

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import FluidPressure
from valve_msgs.msg import DutyCommand, ValveState

from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ
from valve_model_pkg.interface.ros import DIAGNOSTICS_QOS, forward_logging, state_message
from valve_model_pkg.model import default_parameters_path, load_parameters
from valve_model_pkg.model.aot import backend as kernel_backend
from valve_model_pkg.model.bank import ValveBank, sample_of
from valve_model_pkg.nodes.common import (ATMOSPHERIC_PRESSURE_PA, COMMAND_QOS, PRESSURE_QOS,
                                          STATE_QOS, TOPIC_DIAGNOSTICS, TOPIC_DUTY_COMMAND,
                                          TOPIC_OUTPUT_PRESSURE, TOPIC_STATE,
                                          TOPIC_SUPPLY_PRESSURE, DiagnosticLevel,
                                          StartupRefused, declare_bool, declare_float, run_node)
from valve_model_pkg.nodes.sim_status import valve_summary, valve_values
from valve_model_pkg.nodes.simulator_node import declare_electronics
from valve_model_pkg.nodes.tick_loop import TickLoop
from valve_model_pkg.nodes.inputs import (InputGuard, SequenceTracker, accept_duty_command,
                                          accept_pressure)

#: A valve name is one ROS name token: it becomes the first part of the valve's topics.
_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


def _declare_strings(node: Node, name: str, default: list[str], description: str
                     ) -> list[str]:
    descriptor = ParameterDescriptor(description=description,
                                     type=ParameterType.PARAMETER_STRING_ARRAY)
    value = node.declare_parameter(name, list(default), descriptor).value
    return [str(v) for v in (value or [])]


class _Valve:
    """The per-valve bookkeeping of the node: name, publisher, input counters."""

    def __init__(self, node: Node, index: int, name: str, params_path: str) -> None:
        self.index = index
        self.name = name
        self.params_path = params_path
        self.inputs = InputGuard(node.get_logger())
        self.commands = SequenceTracker()
        self.sequence = 0
        self.publisher = node.create_publisher(ValveState, f'{name}/{TOPIC_STATE}', STATE_QOS)


class ValveBankSimulatorNode(Node):
    """Real-time simulation of N PWM-driven solenoid valves in one process."""

    def __init__(self) -> None:
        super().__init__('valve_bank_simulator')
        names = _declare_strings(
            self, 'valve_names', ['valve_0', 'valve_1'],
            'Names of the simulated valves; valve NAME uses the topics NAME/valve/... and '
            'header.frame_id NAME')
        files = _declare_strings(
            self, 'params_files', [''],
            'Valve parameter sets (YAML): one for every valve, or one per valve name (same '
            'order); an empty entry = the paper\'s Table 1/2 values shipped in '
            'config/valve.yaml')
        self._rate_hz = declare_float(self, 'publish_rate_hz', 1000.0,
                                      'Rate of each valve/state stream [Hz]', 1.0, 10000.0)
        duty = declare_float(self, 'duty', 0.0, 'Initial main PWM duty of every valve [1]',
                             0.0, 1.0)
        pwm_hz = declare_float(self, 'pwm_frequency_hz', 50.0,
                               'Initial main PWM frequency of every valve [Hz]',
                               MIN_PWM_FREQUENCY_HZ, MAX_PWM_FREQUENCY_HZ)
        supply_pa = declare_float(
            self, 'supply_pressure_pa', 400_000.0,
            'Supply pressure, gauge [Pa], used until NAME/valve/supply_pressure is received',
            0.0, 1.0e6)
        output_pa = declare_float(
            self, 'output_pressure_pa', 0.0,
            'Output port pressure, gauge [Pa], used until NAME/valve/output_pressure is '
            'received', -ATMOSPHERIC_PRESSURE_PA, 1.0e6)
        supply_voltage = declare_float(self, 'supply_voltage_v', 24.0,
                                       'Drive supply voltage [V]', 0.0, 60.0)
        electronics, electronics_text = declare_electronics(self)
        self._max_advance_s = declare_float(
            self, 'max_advance_per_tick_s', 0.05,
            'Most model time integrated in one tick [s]; bounds the work per callback',
            1e-4, 1.0)
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of the diagnostics summary [s]', 0.05, 60.0)
        allow_implausible = declare_bool(
            self, 'allow_implausible', False,
            'Accept parameter values outside their plausible ranges, with a warning (values '
            'beyond the numerically safe range are refused anyway)')

        paths = self._parameter_paths(names, files)
        forward_logging(self, 'valve_model_pkg.model.parameters')
        loaded: dict[str, object] = {}
        for path in paths:  # each distinct file once; a bad file is refused naming it
            if path not in loaded:
                loaded[path] = load_parameters(path, allow_implausible=allow_implausible)
        params = [loaded[p] for p in paths]
        # Load (or compile) the kernel before the clock starts (see valve_simulator).
        warm_up = ValveBank(params, electronics, supply_voltage, duty=0.5)
        warm_up.advance_to(0.045)
        warm_up.sample_array()
        self._bank = ValveBank(params, electronics, supply_voltage, duty=duty,
                               pwm_frequency_hz=pwm_hz, supply_pressure_pa=supply_pa,
                               output_pressure_pa=output_pa)
        self._valves = [_Valve(self, k, n, p) for k, (n, p) in enumerate(zip(names, paths))]
        for v in self._valves:
            self.create_subscription(DutyCommand, f'{v.name}/{TOPIC_DUTY_COMMAND}',
                                     lambda msg, v=v: self._on_duty(v, msg), COMMAND_QOS)
            self.create_subscription(FluidPressure, f'{v.name}/{TOPIC_SUPPLY_PRESSURE}',
                                     lambda msg, v=v: self._on_pressure(v, msg, 'supply'),
                                     PRESSURE_QOS)
            self.create_subscription(FluidPressure, f'{v.name}/{TOPIC_OUTPUT_PRESSURE}',
                                     lambda msg, v=v: self._on_pressure(v, msg, 'output'),
                                     PRESSURE_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS,
                                               DIAGNOSTICS_QOS)

        self._period_s = 1.0 / self._rate_hz
        # the real-time rules (sample grid, bounded work, clock going backwards)
        self._loop = TickLoop(self._period_s, self._max_advance_s,
                              advance_to=self._bank.advance_to,
                              publish=self._publish_states,
                              restart=self._restart,
                              samples_label='sample(s) of all valves')
        self.create_timer(self._period_s, self._on_tick)
        self.create_timer(diag_period, self._publish_summary)
        self.get_logger().info(
            f'simulating {len(names)} valves ({", ".join(names)}) at {self._rate_hz:g} Hz; '
            f'duty {duty:g} at {pwm_hz:g} Hz, supply {supply_pa:g} Pa gauge, electronics: '
            f'{electronics_text}')
        # which compiled kernel runs: the ahead-of-time module (no numba in the process)
        # or the numba jit (model/aot.py, docs/model.md)
        self.get_logger().info(f'valve kernel: {kernel_backend().origin}')

    @staticmethod
    def _parameter_paths(names: list[str], files: list[str]) -> list[str]:
        """One parameter file per valve; refuses bad names and a misaligned file list."""
        if not names:
            raise StartupRefused('valve_names is empty: name at least one valve')
        for name in names:
            if not _NAME.match(name):
                raise StartupRefused(
                    f'valve_names: {name!r} is not a valid name (a letter, then letters, '
                    'digits or _)')
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise StartupRefused(f'valve_names: {", ".join(dupes)} given more than once')
        if len(files) not in (0, 1, len(names)):
            raise StartupRefused(
                f'params_files has {len(files)} entries for {len(names)} valve_names: give '
                'none, one for all, or one per valve')
        default = str(default_parameters_path())
        if not files:
            return [default] * len(names)
        if len(files) == 1:
            return [files[0] or default] * len(names)
        return [f or default for f in files]

    # --- inputs ---------------------------------------------------------------------------
    def _on_duty(self, v: _Valve, msg: DutyCommand) -> None:
        """A duty command for valve ``v`` (checked as by ``valve_simulator``)."""
        v.commands.update(msg.header.frame_id, msg.sequence)
        accepted = accept_duty_command(msg, v.inputs,
                                       lambda: self._bank.sample(v.index).pwm_frequency_hz,
                                       who=f'{v.name}: ')
        if accepted is not None:
            self._bank.set_command(v.index, *accepted)

    def _on_pressure(self, v: _Valve, msg: FluidPressure, port: str) -> None:
        gauge = accept_pressure(msg, v.inputs, port, who=f'{v.name}: ')
        if gauge is None:
            return
        s = self._bank.sample(v.index)
        supply, output = (gauge, s.output_pressure_pa) if port == 'supply' \
            else (s.supply_pressure_pa, gauge)
        # a message must never end the node: a pressure the model refuses is counted
        try:
            self._bank.set_pressures(v.index, supply, output)
        except ValueError as err:
            v.inputs.reject(f'{port}_pressure', 'model_refused',
                            f'{v.name}: {port} pressure rejected by the model: {err}; '
                            'keeping the last valid value')

    # --- real-time loop -------------------------------------------------------------------
    def _on_tick(self) -> None:
        """Advance every valve to the clock, publishing each sample-grid instant passed.

        The rules of :class:`~valve_model_pkg.nodes.tick_loop.TickLoop`, for all valves at
        once: one compiled call advances the bank to each grid instant, one reads all
        states.
        """
        reason = self._loop.tick(self.get_clock().now().nanoseconds)
        if reason:
            self._publish_diagnostics(DiagnosticLevel.WARN, 'fell behind: ' + reason)

    def _restart(self) -> None:
        self.get_logger().warning('clock went backwards; restarting the models')
        self._bank.reset()

    def _publish_states(self, stamp_ns: int) -> None:
        stamp = Time(nanoseconds=stamp_ns, clock_type=self.get_clock().clock_type).to_msg()
        # one compiled call for every valve's state; tolist() gives Python floats at once
        rows = self._bank.sample_array().tolist()
        source = ValveState.SOURCE_SIMULATOR
        for v, row in zip(self._valves, rows):
            msg = state_message(sample_of(row), stamp, v.name, v.sequence, source)
            v.sequence += 1
            v.publisher.publish(msg)

    # --- diagnostics ----------------------------------------------------------------------
    def _publish_summary(self) -> None:
        self._loop.close_window()
        self._publish_diagnostics(None, '')
        self._loop.max_tick_compute_s = 0.0

    def _publish_diagnostics(self, level: int | None, text: str) -> None:
        """One status per valve; ``level`` None = the periodic summary (level per valve)."""
        rows = self._bank.sample_array().tolist()
        statuses = []
        for v in self._valves:
            s = sample_of(rows[v.index])
            if level is None:
                lvl, msg = valve_summary(self._loop, v.commands, v.inputs)
            else:
                lvl, msg = level, text
            status = DiagnosticStatus(level=lvl, name=f'{self.get_name()}: {v.name} real-time '
                                      'model', message=msg, hardware_id=v.name)
            status.values = valve_values(self._loop, s, rate_hz=self._rate_hz,
                                         sequence=v.sequence, commands=v.commands,
                                         inputs=v.inputs, params_file=v.params_path,
                                         valves_in_process=len(self._valves))
            statuses.append(status)
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = statuses
        self._diag_pub.publish(array)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(ValveBankSimulatorNode, 'valve_bank_simulator', args, events_executor=True)


if __name__ == '__main__':
    main()
