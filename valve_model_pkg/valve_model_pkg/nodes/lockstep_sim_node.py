"""valve_lockstep_sim: valve model(s) and cylinder in one process, on simulation time, in lockstep.

The simulation side of the suite for ``make demo``: it owns the clock. It advances the
valve model(s) and the cylinder together in fixed steps (``step_s``, default 1 ms),
publishes ``/clock`` (rosgraph_msgs/Clock) and, at every control tick
(``control_period_s``, default 5 ms), waits for the controller's answer before it goes on
(protocol: :mod:`valve_model_pkg.pneumatics.lockstep`). Every other node runs with
``use_sim_time``, so a run does not depend on how busy the computer is: the same inputs
give the same run. Wall-clock mode (``valve_simulator`` + ``pneumatic_cylinder``, or the
CAN driver) stays for hardware.

Topics (valve topics per valve namespace: none for the single cylinder, ``cap/`` and
``rod/`` for the double-acting one):

- publishes ``valve/state`` every step, ``valve/output_pressure`` (chamber, absolute Pa),
  ``cylinder/joint_states`` (``piston``: position, velocity, effort = net pressure force;
  for the double cylinder also ``cap_chamber``/``rod_chamber`` with their gauge pressure
  [Pa] as position) and ``/clock`` every control tick, all stamped with simulation time;
- publishes ``simulation/real_time_factor`` (std_msgs/Float64) and ``/diagnostics`` once
  per ``diagnostics_period_s`` of wall time (lockstep timeouts, real-time factor, steps);
- subscribes ``valve/duty_command`` (the answer of each tick) and
  ``simulation/run_until`` (std_msgs/Float64 [s]: hold the simulation at that time).

With ``valve_source:=external`` the valve runs elsewhere (the CAN backend: the controller
emulator on the simulation clock, ``valve_controller_emulator --clock sim``, read through
the CAN driver): every step the node publishes ``/clock`` = the end of the step, waits for
one ``valve/state`` (the valve advanced to that time), and integrates the cylinder over
the step with its spool position; it publishes no ``valve/state`` itself. While it waits
for a step's state it publishes the tick's pressures and joint states again every 0.25 s
(the valve's side needs the tick's duty command and pressure, and one lost before a DDS
match would never come otherwise) with the step's ``/clock``. A step whose valve state
does not come within ``lockstep_timeout_s`` is a lockstep timeout too (the last opening
is held). Before the first step it waits for one ``valve/state`` per valve
at t = 0 (the start handshake, :class:`~valve_model_pkg.pneumatics.lockstep.StartHandshake`:
the emulator sends its t = 0 frames once the driver is on the bus), re-publishing
``/clock`` = 0 meanwhile; only then is the first step's state sure to find the chain up.
It reads an external valve's states with ``STATE_DURABLE_QOS`` (the driver's writer
keeps them for a reader it matches late), so that one t = 0 state is never lost.

A duty command that is not finite or has an impossible frequency is rejected and counted
(the last valid command stays); a duty outside [0, 1] is clamped and counted.
"""
from __future__ import annotations

import dataclasses
import math
import time

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from valve_msgs.msg import DutyCommand, ValveState

from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, MAX_PWM_FREQUENCY_HZ,
                                       MIN_PWM_FREQUENCY_HZ, TOPIC_CLOCK, TOPIC_DIAGNOSTICS,
                                       TOPIC_DUTY_COMMAND, TOPIC_JOINT_STATES,
                                       TOPIC_OUTPUT_PRESSURE, TOPIC_REAL_TIME_FACTOR,
                                       TOPIC_RUN_UNTIL, TOPIC_STATE)
from valve_model_pkg.interface.ros import (CLOCK_QOS, COMMAND_QOS, DIAGNOSTICS_QOS,
                                           JOINT_STATES_QOS,
                                           PRESSURE_QOS, STATE_DURABLE_QOS, STATE_QOS,
                                           state_message)
from valve_model_pkg.model import ElectronicsConfig, default_parameters_path, load_parameters
from valve_model_pkg.nodes.common import (DiagnosticLevel, declare_bool, declare_float,
                                          declare_string, key_values, run_node)
from valve_model_pkg.nodes.inputs import InputGuard, SequenceTracker, stamp_reason
from valve_model_pkg.pneumatics.axis import CYLINDER_KINDS, SimulatedAxis
from valve_model_pkg.pneumatics.cylinder import PARAMETER_INFO, CylinderParameters
from valve_model_pkg.pneumatics.lockstep import (LockstepGate, Pacer, RealTimeFactor,
                                                 StartHandshake)

#: Longest a timer callback keeps stepping before the executor gets its turn [s].
_BUDGET_S = 0.02
#: Wall time a wait (for a tick's answers, an external valve's state, the start
#: handshake) lasts before this node publishes what the wait needs again [s]. A message
#: published before its DDS writer matched a reader is lost for that reader; the resends
#: carry the same data, so when they come changes nothing but the wall time.
_RESEND_S = 0.25


def _stamp(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def valve_topic(namespace: str, topic: str) -> str:
    """``topic`` in a valve's namespace ('' = none)."""
    return f'{namespace}/{topic}' if namespace else topic


class LockstepSimulationNode(Node):
    """The valve model(s) and the cylinder, on a simulation clock, in lockstep."""

    def __init__(self) -> None:
        super().__init__('valve_lockstep_sim')
        kind = declare_string(self, 'cylinder', 'single',
                              'single: single-acting cylinder, one valve; double: '
                              'double-acting, one 3/2 valve per chamber (cap/, rod/)')
        if kind not in CYLINDER_KINDS:
            raise ValueError(f'parameter \'cylinder\' = {kind!r}: expected one of '
                             f'{", ".join(CYLINDER_KINDS)}')
        params_file = declare_string(self, 'params_file', '',
                                     'Valve parameter set (YAML); empty = config/valve.yaml')
        step_s = declare_float(self, 'step_s', 0.001,
                               'Simulation step = valve/state period [s]', 1e-4, 0.01)
        control_s = declare_float(self, 'control_period_s', 0.005,
                                  'Control tick: joint states, pressures, /clock and the '
                                  'lockstep wait [s]; a multiple of step_s', 1e-4, 0.1)
        self._lockstep = declare_bool(self, 'lockstep', True,
                                      'Wait at every control tick for each valve\'s duty '
                                      'command stamped with that tick')
        timeout = declare_float(self, 'lockstep_timeout_s', 10.0,
                                'Wall time to wait for a tick\'s duty commands before going '
                                'on without them (counted and reported) [s]', 0.01, 60.0)
        rtf_max = declare_float(self, 'real_time_factor_max', 1.0,
                                'Most simulation seconds per wall second; 0 = as fast as '
                                'possible', 0.0, 1000.0)
        source = declare_string(self, 'valve_source', 'model',
                                'model: the valve model(s) run here; external: valve/state '
                                'comes from another process stepped on /clock (the CAN '
                                'driver + emulator with --clock sim)')
        if source not in ('model', 'external'):
            raise ValueError(f'parameter \'valve_source\' = {source!r}: expected model or '
                             'external')
        self._external = source == 'external'
        self._step_pending = False
        self._step_requested_s = 0.0
        self._openings: dict[str, float] = {}
        self._last_openings: dict[str, float] = {}
        self._start_paused = declare_bool(self, 'start_paused', False,
                                          'Hold at t = 0 until simulation/run_until arrives')
        supply_pa = declare_float(self, 'supply_pressure_pa', 400_000.0,
                                  'Supply pressure, gauge [Pa]', 0.0, 1.0e6)
        pwm_hz = declare_float(self, 'pwm_frequency_hz', 50.0, 'Initial main PWM frequency '
                               '[Hz]', MIN_PWM_FREQUENCY_HZ, MAX_PWM_FREQUENCY_HZ)
        supply_v = declare_float(self, 'supply_voltage_v', 24.0, 'Drive supply [V]', 0.0, 60.0)
        y0 = declare_float(self, 'initial_position_m', 0.0, 'Initial piston position [m]',
                           0.0, 2.0)
        diag_period = declare_float(self, 'diagnostics_period_s', 1.0,
                                    'Period of diagnostics and real-time factor, wall [s]',
                                    0.05, 60.0)
        defaults = CylinderParameters()
        plant = {name: declare_float(self, f'plant.{name}', getattr(defaults, name), text,
                                     low, high)
                 for name, (text, low, high) in PARAMETER_INFO.items()}
        self._step_ns = int(round(step_s * 1e9))
        self._control_ns = int(round(control_s * 1e9))
        if self._control_ns % self._step_ns:
            raise ValueError(f'parameter \'control_period_s\' = {control_s!r} is not a '
                             f'multiple of step_s = {step_s!r}')
        path = params_file or str(default_parameters_path())
        valve = load_parameters(path)
        self._axis = SimulatedAxis(kind, step_ns=self._step_ns, valve=valve,
                                   plant=dataclasses.replace(defaults, **plant),
                                   supply_pressure_pa=supply_pa, pwm_frequency_hz=pwm_hz,
                                   electronics=ElectronicsConfig(), supply_voltage_v=supply_v,
                                   initial_position_m=y0)
        self._axis.step()  # compiles/loads the model's kernel now, not on the first tick
        self._axis = SimulatedAxis(kind, step_ns=self._step_ns, valve=valve,
                                   plant=dataclasses.replace(defaults, **plant),
                                   supply_pressure_pa=supply_pa, pwm_frequency_hz=pwm_hz,
                                   electronics=ElectronicsConfig(), supply_voltage_v=supply_v,
                                   initial_position_m=y0)
        self._names = self._axis.names
        self._gate = LockstepGate(self._names, timeout)
        # External valve: no first step before its t = 0 state came (protocol: the module
        # docstring of pneumatics/lockstep).
        self._handshake = StartHandshake(self._names, timeout) if self._external else None
        self._pacer = Pacer(rtf_max)
        self._rtf = RealTimeFactor()
        self._run_until_ns: int | None = 0 if self._start_paused else None
        self._holding = self._start_paused
        self._inputs = InputGuard(self.get_logger())
        self._commands = {n: SequenceTracker() for n in self._names}
        self._stale_answers = 0   # older ticks' duty answers that came again: not applied
        self._sequence = {n: 0 for n in self._names}
        self._last_resend = 0.0
        # The last tick's messages, as published (sent again while a step waits for them)
        self._tick_pressures: dict[str, FluidPressure] = {}
        self._tick_joint: JointState | None = None

        self._clock_pub = self.create_publisher(ClockMsg, TOPIC_CLOCK, CLOCK_QOS)
        self._state_pubs = {} if self._external else {
            n: self.create_publisher(ValveState, valve_topic(n, TOPIC_STATE), STATE_QOS)
            for n in self._names}
        # An external valve's states: durable, so the one t = 0 state of the start
        # handshake reaches this reader however late the driver's writer matches it.
        self._state_subs = {n: self.create_subscription(
            ValveState, valve_topic(n, TOPIC_STATE), lambda msg, n=n: self._on_state(n, msg),
            STATE_DURABLE_QOS) for n in self._names} if self._external else {}
        self._pressure_pubs = {n: self.create_publisher(
            FluidPressure, valve_topic(n, TOPIC_OUTPUT_PRESSURE), PRESSURE_QOS)
            for n in self._names}
        self._joint_pub = self.create_publisher(JointState, TOPIC_JOINT_STATES,
                                                JOINT_STATES_QOS)
        self._rtf_pub = self.create_publisher(Float64, TOPIC_REAL_TIME_FACTOR, COMMAND_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS,
                                               DIAGNOSTICS_QOS)
        for n in self._names:
            self.create_subscription(DutyCommand, valve_topic(n, TOPIC_DUTY_COMMAND),
                                     lambda msg, n=n: self._on_duty(n, msg), COMMAND_QOS)
        self.create_subscription(Float64, TOPIC_RUN_UNTIL, self._on_run_until, COMMAND_QOS)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(0.001, self._advance, clock=steady)
        self.create_timer(diag_period, self._publish_diagnostics, clock=steady)
        self._publish_tick()  # t = 0: the clock exists before the first step
        self.get_logger().info(
            f'lockstep simulation: {kind} cylinder, valve(s) {list(self._names)}, step '
            f'{step_s * 1e3:g} ms, control tick {control_s * 1e3:g} ms, lockstep '
            f'{self._lockstep}, real-time factor cap '
            f'{"none" if rtf_max <= 0 else f"{rtf_max:g}"}, '
            f'{"held until simulation/run_until" if self._start_paused else "running"}')

    # --- inputs ---------------------------------------------------------------------------
    def _on_duty(self, name: str, msg: DutyCommand) -> None:
        self._commands[name].update(msg.header.frame_id, msg.sequence)
        duty, freq = float(msg.duty), float(msg.pwm_frequency)
        topic = valve_topic(name, 'duty_command')
        keep = '; keeping the last valid command'
        if not math.isfinite(duty) or not math.isfinite(freq):
            self._inputs.reject(topic, 'not_finite', f'duty command rejected: duty={duty!r}, '
                                f'pwm_frequency={freq!r} is not finite' + keep)
            return
        if freq != 0.0 and not MIN_PWM_FREQUENCY_HZ <= freq <= MAX_PWM_FREQUENCY_HZ:
            self._inputs.reject(topic, 'frequency_out_of_range',
                                f'duty command rejected: pwm_frequency={freq!r} Hz' + keep)
            return
        reason = stamp_reason(msg.header.stamp)
        if reason is not None:
            self._inputs.reject(topic, 'bad_stamp', f'duty command rejected: {reason}' + keep)
            return
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self._lockstep and self._gate.is_stale(name, stamp_ns):
            self._stale_answers += 1   # an older tick's answer, sent again: the newer stays
            return
        if freq == 0.0:
            freq = self._axis.sample(name).pwm_frequency_hz
        if not 0.0 <= duty <= 1.0:
            clamped = min(max(duty, 0.0), 1.0)
            self._inputs.reject(topic, 'duty_clamped',
                                f'duty {duty!r} outside [0, 1]; clamped to {clamped:g}')
            duty = clamped
        self._axis.set_command(name, duty, freq)
        was_waiting = self._gate.waiting
        self._gate.answer(name, stamp_ns, time.monotonic())
        if was_waiting and not self._gate.waiting:
            self._advance()  # answered: go on at once, not at the next timer tick

    def _on_run_until(self, msg: Float64) -> None:
        value = float(msg.data)
        if not math.isfinite(value) or value < 0.0:
            self._inputs.reject('run_until', 'out_of_range',
                                f'simulation/run_until {value!r} s rejected')
            return
        # On the step grid, so the hold lands exactly on a tick.
        self._run_until_ns = int(round(value * 1e9 / self._step_ns)) * self._step_ns
        if self._holding:
            self._holding = False
            self._pacer.restart(time.monotonic(), self._axis.t_ns)

    # --- the loop -------------------------------------------------------------------------
    def _advance(self) -> None:
        """Step while allowed: not waiting for a tick's answer, not held, on pace."""
        start = time.monotonic()
        while True:
            wall = time.monotonic()
            if self._step_pending:
                if wall - self._step_requested_s > self._gate.timeout_s:
                    self._gate.timeouts += 1
                    self._gate.last_timeout = (
                        f'no valve/state for t = {(self._axis.t_ns + self._step_ns) * 1e-9:.3f}'
                        f' s within {self._gate.timeout_s:g} s')
                    self.get_logger().warning(f'lockstep timeout: {self._gate.last_timeout}; '
                                              'holding the last opening',
                                              throttle_duration_sec=1.0)
                    self._finish_step()
                    continue
                if wall - self._last_resend > _RESEND_S and \
                        wall - self._step_requested_s > _RESEND_S:
                    self._last_resend = wall
                    self._resend_step_request()
                return
            if self._gate.waiting:
                if self._gate.check_timeout(wall):
                    self.get_logger().warning(
                        f'lockstep timeout: {self._gate.last_timeout}; going on with the '
                        'command in force (this run is no longer deterministic)',
                        throttle_duration_sec=1.0)
                    self._pacer.restart(wall, self._axis.t_ns)
                    continue
                if wall - self._last_resend > _RESEND_S and \
                        wall - self._gate.waiting_since_s > _RESEND_S:
                    self._last_resend = wall
                    self._publish_tick()  # for a node that started late
                return
            if self._run_until_ns is not None and self._axis.t_ns >= self._run_until_ns:
                self._holding = True
                if wall - self._last_resend > _RESEND_S:
                    # the clock of the hold, for a node that started (or matched) late
                    self._last_resend = wall
                    self._publish_clock(self._axis.t_ns)
                return
            if self._handshake is not None and not self._handshake.ready:
                if self._handshake.check_timeout(wall):
                    self._gate.timeouts += 1
                    self._gate.last_timeout = self._handshake.last_timeout
                    self.get_logger().warning(f'lockstep timeout: {self._gate.last_timeout}; '
                                              'asking for the first step anyway')
                    self._pacer.restart(wall, self._axis.t_ns)
                    continue
                if wall - self._last_resend > _RESEND_S:
                    # the t = 0 clock, for an emulator that started (or matched) late
                    self._last_resend = wall
                    self._publish_clock(self._axis.t_ns)
                return
            if self._lockstep and not self._external and self._gate.tick_ns is None:
                # the t = 0 tick (published at start) is answered like every other one
                # before the first step: else the first 5 ms would run with whichever
                # answers are in when the hold ends (an external valve's side holds its
                # own gate on each tick's command, the first included)
                self._gate.open_tick(self._axis.t_ns, wall)
                self._pacer.restart(wall, self._axis.t_ns)
                continue
            if not self._pacer.may_step(wall, self._axis.t_ns):
                return
            if wall - start > _BUDGET_S:
                return
            self._step()

    def _on_state(self, name: str, msg: ValveState) -> None:
        """External valve: its state at the end of the requested step."""
        if not math.isfinite(msg.spool_position):
            self._inputs.reject(valve_topic(name, 'state'), 'not_finite',
                                f'valve/state spool_position {msg.spool_position!r} rejected')
            return
        if not self._step_pending:
            handshake = self._handshake
            if handshake is not None and self._axis.t_ns == 0 and handshake.state(name):
                self.get_logger().info('start handshake: valve/state at t = 0 from every '
                                       'valve; the chain emulator -> CAN -> driver -> '
                                       'valve/state is up')
                self._pacer.restart(time.monotonic(), self._axis.t_ns)
                self._advance()
            return  # not a step's state (the t = 0 state of the start handshake)
        if name in self._openings:
            return  # not asked for
        self._openings[name] = max(0.0, float(msg.spool_position))
        if all(n in self._openings for n in self._names):
            self._finish_step()
            self._advance()

    def _finish_step(self) -> None:
        """External valve: integrate the cylinder over the requested step."""
        openings = {n: self._openings.get(n, self._last_openings.get(n, 0.0))
                    for n in self._names}
        self._last_openings = openings
        self._openings = {}
        self._step_pending = False
        self._axis.step_with_openings(openings)
        self._after_step(publish_states=False)

    def _resend_step_request(self) -> None:
        """External valve, its step's state overdue: ask again, with what the step needs.

        The valve's side advances past a control tick only with that tick's duty command
        and output pressure (:mod:`valve_driver_pkg.emulator.lockstep`); one lost on its
        way there (published before a DDS match) would stall the step. So the tick's
        pressures and joint states go out again (the controller answers a tick again with
        the same flow command, ``flow_to_duty`` with the same duty command), and the
        step's ``/clock``. The tick's ``/clock`` does not: the clock never goes back.
        """
        for n, msg in self._tick_pressures.items():
            self._pressure_pubs[n].publish(msg)
        if self._tick_joint is not None:
            self._joint_pub.publish(self._tick_joint)
        self._clock_pub.publish(ClockMsg(clock=_stamp(self._axis.t_ns + self._step_ns)))

    def _step(self) -> None:
        if self._external:
            # Ask the valve to advance to the end of the step (protocol: emulator/lockstep)
            self._step_pending = True
            self._step_requested_s = time.monotonic()
            self._clock_pub.publish(ClockMsg(clock=_stamp(self._axis.t_ns + self._step_ns)))
            return
        self._axis.step()
        self._after_step(publish_states=True)

    def _after_step(self, publish_states: bool) -> None:
        t_ns = self._axis.t_ns
        stamp = _stamp(t_ns)
        for n in self._names if publish_states else ():
            msg = state_message(self._axis.sample(n), stamp, n or 'valve', self._sequence[n],
                                ValveState.SOURCE_SIMULATOR)
            self._sequence[n] += 1
            self._state_pubs[n].publish(msg)
        if t_ns % self._control_ns == 0:
            self._publish_tick()
            if self._lockstep:
                self._gate.open_tick(t_ns, time.monotonic())
        self._rtf.update(time.monotonic(), t_ns)

    def _publish_tick(self) -> None:
        """Pressures, joint states, then /clock, stamped with the tick (protocol step 1)."""
        t_ns = self._axis.t_ns
        stamp = _stamp(t_ns)
        self._tick_pressures = {}
        for n in self._names:
            p = FluidPressure()
            p.header.stamp = stamp
            p.header.frame_id = f'{n}_chamber' if n else 'cylinder_chamber'
            p.fluid_pressure = self._axis.chamber_gauge_pressure_pa(n) + ATMOSPHERIC_PRESSURE_PA
            self._pressure_pubs[n].publish(p)
            self._tick_pressures[n] = p
        cyl = self._axis.cylinder
        state = cyl.state
        joint = JointState()
        joint.header.stamp = stamp
        joint.name = ['piston']
        joint.position = [state.position_m]
        joint.velocity = [state.velocity_m_s]
        joint.effort = [cyl.net_pressure_force_n()]
        if self._axis.kind == 'double':
            for n in self._names:
                joint.name.append(f'{n}_chamber')
                joint.position.append(self._axis.chamber_gauge_pressure_pa(n))
                joint.velocity.append(0.0)
                joint.effort.append(0.0)
        self._joint_pub.publish(joint)
        self._tick_joint = joint
        self._publish_clock(t_ns)

    def _publish_clock(self, t_ns: int) -> None:
        """``/clock`` = ``t_ns``.

        During the start handshake too, whether or not the driver is up: the emulator
        sends its t = 0 frames once, on the first ``/clock`` after the driver is on the
        bus, and the driver's ``valve/state`` writer keeps that state for this node's
        reader however late the two match (``STATE_DURABLE_QOS``).
        """
        self._clock_pub.publish(ClockMsg(clock=_stamp(t_ns)))

    # --- diagnostics ----------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        wall = time.monotonic()
        rtf = self._rtf.last_window if not self._holding else 0.0
        self._rtf_pub.publish(Float64(data=float(rtf)))
        level, text = DiagnosticLevel.OK, 'in lockstep' if self._lockstep else 'free running'
        if self._holding:
            text = f'held at t = {self._axis.t_ns * 1e-9:.3f} s'
        elif self._handshake is not None and not self._handshake.ready:
            text = 'waiting for valve/state at t = 0 (start handshake)'
        elif self._gate.waiting and wall - self._gate.waiting_since_s > _RESEND_S:
            text = (f'waiting {wall - self._gate.waiting_since_s:.1f} s for the duty '
                    f'command(s) of t = {self._gate.tick_ns * 1e-9:.3f} s')
        problems = []
        if self._gate.timeouts:
            problems.append(f'{self._gate.timeouts} lockstep timeout(s); last: '
                            f'{self._gate.last_timeout}')
        if self._inputs.total:
            problems.append(f'{self._inputs.total} message(s) rejected; last: '
                            f'{self._inputs.last_reason}')
        if problems:
            level, text = DiagnosticLevel.WARN, '; '.join(problems)
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: lockstep simulation',
                                  message=text, hardware_id='simulation')
        lost = {f'{n or "valve"}_duty_commands_lost': self._commands[n].lost
                for n in self._names}
        status.values = key_values(
            simulation_time_s=self._axis.t_ns * 1e-9, steps=self._axis.steps,
            real_time_factor=rtf, real_time_factor_max=self._pacer.max_factor,
            lockstep=self._lockstep, lockstep_ticks=self._gate.ticks,
            lockstep_timeouts=self._gate.timeouts,
            lockstep_max_wait_s=self._gate.max_wait_s,
            last_lockstep_timeout=self._gate.last_timeout, held=self._holding,
            start_handshake=('none' if self._handshake is None else 'gave up'
                             if self._handshake.gave_up else 'done'
                             if self._handshake.ready else 'waiting'),
            stale_duty_answers=self._stale_answers,
            rejected_messages=self._inputs.total, **lost,
            **self._inputs.diagnostic_values())
        array = DiagnosticArray()
        array.header.stamp = _stamp(self._axis.t_ns)
        array.status = [status]
        self._diag_pub.publish(array)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C or an external shutdown."""
    run_node(LockstepSimulationNode, 'valve_lockstep_sim', args, events_executor=True)


if __name__ == '__main__':
    main()
