"""The controller emulator on the simulation clock: ``valve_controller_emulator --clock sim``.

With the CAN backend in lockstep (``valve_demo --backend can``, the default clock), the
valve model runs in the emulator, the cylinder in ``valve_lockstep_sim`` with
``valve_source:=external``, and the emulator's model advances on the simulation clock instead
of the wall clock:

1. ``valve_lockstep_sim`` publishes ``/clock`` = t, the end of the next valve step.
2. This bridge advances the emulator's model to t (:meth:`ControllerEmulator.step`, every
   frame due up to t, exactly as in real time: telemetry and its mean, period, status)
   and so sends one ``ValveTelemetry`` per valve step.
3. The CAN driver (``use_sim_time``) publishes it as ``valve/state``, stamped with the
   frame's timestamp, which here is the model instant (simulation time) of its values;
   the simulation integrates the cylinder over the step with that opening, and at a
   control tick T publishes the pressure and joint state and waits for
   ``valve/duty_command`` stamped T, as with its own valve.
4. Before the model advances past a control tick T, the bridge waits until the command
   the emulator received over CAN is the duty command stamped T (the bridge sees that
   command on ROS too, only to know which duty the tick needs; the valve takes it from
   the bus as it would on hardware). The driver's CAN frame and the simulation's next
   ``/clock`` race; this wait makes the run the same whichever comes first.
5. The same holds for the chamber (output) pressure the simulation publishes at tick T:
   the driver forwards it in a ``ValvePressure`` frame, and the model does not advance
   past T until the bridge has seen the pressure stamped T on ROS and that frame's
   pressure is the one stamped T. Without this the pressure reached the valve one or two
   steps early or late depending on the computer's load.
6. Nothing here waits for a message that may never come: a duty command or pressure
   published before its DDS writer matched the bridge's (or the driver's) reader is lost
   for it, and the simulation, whose step then waits for its ``valve/state``, publishes
   tick T's pressure and joint states again (the controller and ``flow_to_duty`` answer
   them again with the same commands) until the step's state comes. A wait ends when
   what the tick needs arrives, however long the computer took; only one of more than
   ``timeout_s`` is a timeout.

Start handshake. The emulator sends its t = 0 frames (the valve at rest) not when it
starts but once, when the whole chain can carry them: an enabling ``ValveCommand`` or a
``ValvePressure`` from the host (the CAN driver sends these only while active, so it is on
the bus and publishes what it receives; an inactive one may send ``Enable`` 0 frames,
which do not count) and then a ``/clock`` from the simulation arrived. The model does not
advance before that. The simulation in turn does not ask for the first step until that
t = 0 ``valve/state`` has reached it (``valve_lockstep_sim``,
:class:`valve_model_pkg.pneumatics.lockstep.StartHandshake`); the driver's state writer
keeps it for the simulation's reader however late the two match (``STATE_DURABLE_QOS``).
A telemetry frame sent before the driver is on the bus reaches nobody and cannot be sent
again (the model has advanced past its time); the t = 0 frames are sent exactly once, so
no state the simulation did not ask for can arrive once it asked for a step.

The first control tick (t = 0) is gated like every other once a node publishes the
valve's duty commands (a controller chain is in the graph): the simulation gates its own
valves' t = 0 tick on their answers, and a model that took whatever the bus carried when
the clock first moved would run the first 5 ms with duty 0 or with the t = 0 answer
depending on which process the computer ran first. Without a duty publisher (the chain
alone, no controller) the t = 0 tick runs on the command in force, duty 0.

A tick whose command or pressure does not arrive within ``timeout_s`` of wall time is a
*lockstep timeout*: the model goes on with the command in force, the bridge logs it (what
was missing: the ROS message, or the frame on the bus) and counts it
(``stats['lockstep_timeouts']``). The emulator has no overruns in this mode: model time
never runs ahead of what it has computed (``max_burst`` 0: every telemetry instant is sent).
"""
from __future__ import annotations

import logging
import math
import threading
import time

import can

from valve_driver_pkg.protocol.codec import COMMAND, PRESSURE

__all__ = ['run_on_simulation_clock', 'LockstepGateState']

logger = logging.getLogger('valve_controller_emulator')

#: A CAN duty equals a ROS duty when they differ by at most the frame's resolution [1].
_DUTY_RESOLUTION = 1.5e-4
#: ... and a CAN pressure a ROS one within its resolution (50 Pa per bit, rounded) [Pa].
_PRESSURE_RESOLUTION_PA = 26.0


class LockstepGateState:
    """What the bridge knows: the target time, the tick commands, the command on the bus.

    ROS-free, so the rule "advance past tick T only with tick T's command in force" is
    tested alone.
    """

    def __init__(self, control_period_ns: int, timeout_s: float = 10.0) -> None:
        self.control_ns = int(control_period_ns)
        self.timeout_s = float(timeout_s)
        self.target_ns = 0
        self.tick_duty: dict[int, float] = {}   # duty command stamp [ns] -> duty
        self.bus_duty: float | None = None       # the last ValveCommand duty (Enable=0: 0)
        self.tick_output_pa: dict[int, float] = {}  # pressure stamp [ns] -> gauge [Pa]
        self.bus_output_pa: float | None = None  # the last ValvePressure output (gauge)
        self.waiting_since: float | None = None
        self.released_tick: int | None = None   # the last tick a timeout let go
        self.timeouts = 0
        self.last_timeout = ''
        self.host_seen = False    # an enabling ValveCommand or a ValvePressure: driver active
        self.clock_seen = False   # a /clock from the simulation came after the host was seen
        self.started = False      # the t = 0 frames went out (the start handshake)
        self.gate_first_tick = False  # a node publishes duty commands: t = 0 is gated too

    def start_due(self) -> bool:
        """Whether the t = 0 frames are to be sent now (True once, then never again).

        They go once the driver is on the bus (a host frame arrived) and then a ``/clock``
        of the simulation arrived: sent earlier, the driver may not receive them (or drop
        them while inactive), or the driver's ``valve/state`` may not reach the simulation
        yet, which waits for that t = 0 state before its first step.
        """
        if self.started or not (self.host_seen and self.clock_seen):
            return False
        self.started = True
        return True

    def tick_of(self, model_ns: int) -> int:
        """The control tick whose command governs the step that starts at ``model_ns``."""
        return model_ns // self.control_ns * self.control_ns

    def may_step(self, model_ns: int, wall_s: float) -> bool:
        """Whether the model may advance one step from ``model_ns`` now.

        Past a control tick T only with T's duty command and T's output pressure (both
        stamped T on ROS) on the bus; a wait of more than ``timeout_s`` of wall time
        releases the tick with what the bus carries, counted and described in
        ``last_timeout``.
        """
        tick = self.tick_of(model_ns)
        if (tick == 0 and not self.gate_first_tick) or tick == self.released_tick:
            return True  # no controller chain: the first tick runs with duty 0
        missing = self.missing(tick)
        if missing is None:
            self.waiting_since = None
            return True
        if self.waiting_since is None:
            self.waiting_since = wall_s
            return False
        if wall_s - self.waiting_since > self.timeout_s:
            self.timeouts += 1
            self.last_timeout = (f'no {missing} for tick t = {tick * 1e-9:.3f} s reached '
                                 f'the emulator within {self.timeout_s:g} s')
            self.released_tick = tick   # its remaining steps go on with the bus's values
            self.waiting_since = None
            return True
        return False

    def missing(self, tick: int) -> str | None:
        """What tick ``tick`` still lacks on the bus, in words; None if nothing.

        Says whether the tick's value never came on ROS or the bus carries another one
        (a lost ROS message and a CAN frame not yet sent are different faults).
        """
        duty = self.tick_duty.get(tick)
        if duty is None:
            return 'duty command (none stamped with the tick came on ROS)'
        if self.bus_duty is None or abs(duty - self.bus_duty) > _DUTY_RESOLUTION:
            bus = 'none' if self.bus_duty is None else f'{self.bus_duty:.4f}'
            return f'duty command (the tick\'s is {duty:.4f}, the bus carries {bus})'
        want = self.tick_output_pa.get(tick)
        if want is None:
            return 'output pressure (none stamped with the tick came on ROS)'
        if self.bus_output_pa is None or \
                abs(want - self.bus_output_pa) > _PRESSURE_RESOLUTION_PA:
            bus = 'none' if self.bus_output_pa is None else f'{self.bus_output_pa:.0f} Pa'
            return f'output pressure (the tick\'s is {want:.0f} Pa, the bus carries {bus})'
        return None

    def forget_before(self, tick_ns: int) -> None:
        """Drop the commands and pressures of ticks before ``tick_ns`` (bounded memory)."""
        for stamp in [s for s in self.tick_duty if s < tick_ns]:
            del self.tick_duty[stamp]
        for stamp in [s for s in self.tick_output_pa if s < tick_ns]:
            del self.tick_output_pa[stamp]


def run_on_simulation_clock(emulator, stop: threading.Event, *, step_s: float = 0.001,
                            control_period_s: float = 0.005, timeout_s: float = 10.0,
                            valve_namespace: str = '') -> dict:
    """Run ``emulator`` on the simulation clock until ``stop`` is set; returns counters.

    Two threads: the bus thread hands every received frame to the emulator (and notes the
    duty of each ``ValveCommand``), the ROS thread takes ``/clock`` and the duty commands;
    whichever changes what the gate knows tries to advance the model.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import FluidPressure
    from valve_msgs.msg import DutyCommand

    from valve_model_pkg.interface import (TOPIC_CLOCK, TOPIC_DUTY_COMMAND,
                                           TOPIC_OUTPUT_PRESSURE, gauge_from_absolute)
    from valve_model_pkg.interface.ros import CLOCK_QOS, COMMAND_QOS, PRESSURE_QOS

    step_ns = int(round(step_s * 1e9))
    # the model time is the simulation clock: frames carry it, so the driver on that
    # clock stamps each state with its model instant, not with when it arrived
    emulator.model_time_stamps = True
    gate = LockstepGateState(int(round(control_period_s * 1e9)), timeout_s)
    lock = threading.RLock()
    model_ns = [0]

    def advance() -> None:
        with lock:
            if gate.start_due():
                emulator.step(0.0, 0)   # the t = 0 frames: the simulation's start handshake
                logger.info('start handshake: the driver is on the bus and the simulation\'s '
                            'clock arrived; t = 0 frames sent')
            if not gate.started:
                return   # the model does not advance before the t = 0 frames went out
            while model_ns[0] < gate.target_ns:
                if not gate.may_step(model_ns[0], time.monotonic()):
                    return
                if gate.timeouts and gate.waiting_since is None and gate.last_timeout:
                    logger.warning('lockstep timeout: %s; going on with the command in '
                                   'force', gate.last_timeout)
                    gate.last_timeout = ''
                model_ns[0] += step_ns
                emulator.step(model_ns[0] * 1e-9, 0)
                gate.forget_before(gate.tick_of(model_ns[0]))

    codec = emulator.codec

    def bus_loop() -> None:
        while not stop.is_set():
            try:
                msg = emulator.bus.recv(0.05)
            except can.CanError as err:
                logger.error('emulator: bus receive failed (%s); stopping', err)
                stop.set()
                return
            if msg is None:
                with lock:
                    advance()  # a timed-out wait is decided here too
                continue
            found = codec.classify(msg.arbitration_id)
            emulator.handle(msg)
            if found is not None and found[0] == COMMAND:
                try:
                    signals = codec.decode(msg).signals
                except Exception:   # the emulator counted the bad frame; not a command
                    continue
                with lock:
                    gate.bus_duty = float(signals['Duty']) if signals['Enable'] else 0.0
                    # Only an enabling command shows an active driver: an inactive one
                    # sends ClearFaults frames (Enable 0) too, and would drop the t = 0
                    # telemetry the start handshake sends once.
                    if signals['Enable']:
                        gate.host_seen = True
                    advance()
            elif found is not None and found[0] == PRESSURE:
                try:
                    signals = codec.decode(msg).signals
                except Exception:   # counted by the emulator; not a pressure
                    continue
                with lock:
                    gate.bus_output_pa = float(signals['OutputPressure'])
                    gate.host_seen = True
                    advance()

    from rclpy.signals import SignalHandlerOptions
    # The program's own SIGINT/SIGTERM handlers set ``stop``; rclpy must not replace them.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('valve_emulator_clock')
    duty_topic = f'{valve_namespace}/{TOPIC_DUTY_COMMAND}' if valve_namespace \
        else TOPIC_DUTY_COMMAND

    def on_clock(msg: Clock) -> None:
        t = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        if model_ns[0] == 0 and not gate.gate_first_tick:
            # Decided before the first step (on the executor's thread) and kept: a tick
            # half run without its gate is not gated afterwards.
            gate.gate_first_tick = node.count_publishers(duty_topic) > 0
        with lock:
            gate.clock_seen = gate.clock_seen or gate.host_seen
            if t > gate.target_ns:
                gate.target_ns = t
            advance()

    def on_duty(msg: DutyCommand) -> None:
        t = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with lock:
            if t % gate.control_ns == 0 and t >= gate.tick_of(model_ns[0]):
                gate.tick_duty[t] = min(max(float(msg.duty), 0.0), 1.0)
            advance()

    def on_output_pressure(msg: FluidPressure) -> None:
        t = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with lock:
            if t % gate.control_ns == 0 and t >= gate.tick_of(model_ns[0]) and \
                    math.isfinite(msg.fluid_pressure):
                gate.tick_output_pa[t] = gauge_from_absolute(float(msg.fluid_pressure))
            advance()

    pressure_topic = f'{valve_namespace}/{TOPIC_OUTPUT_PRESSURE}' if valve_namespace \
        else TOPIC_OUTPUT_PRESSURE
    node.create_subscription(Clock, TOPIC_CLOCK, on_clock, CLOCK_QOS)
    node.create_subscription(FluidPressure, pressure_topic, on_output_pressure, PRESSURE_QOS)
    node.create_subscription(DutyCommand, duty_topic, on_duty, COMMAND_QOS)
    from valve_model_pkg.nodes.common import make_executor
    # One round trip through the bridge per simulated millisecond: the C++ executor.
    executor, _ = make_executor(node, events=True)
    executor.add_node(node)
    bus_thread = threading.Thread(target=bus_loop, name='emulator_bus', daemon=True)
    bus_thread.start()
    logger.info('on the simulation clock: step %g ms, control tick %g ms, lockstep timeout '
                '%g s', step_s * 1e3, control_period_s * 1e3, timeout_s)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stop.set()
        bus_thread.join(timeout=1.0)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return {'simulation_time_s': model_ns[0] * 1e-9, 'lockstep_timeouts': gate.timeouts}
