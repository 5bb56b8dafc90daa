"""valve_demo: a user's day with the suite, as separate processes, ending with a report.

This is what ``make demo`` runs. It starts, each as its own process (the ``launch``
package is not in the ROS 2 wheels; users with a full ROS install have
``ros2 launch valve_bringup valve_suite.launch.py``):

- the simulation: by default ``valve_lockstep_sim`` -- valve model(s) and cylinder in one
  process on simulation time, in lockstep with the controller (``--clock lockstep``); with
  ``--clock wall`` the wall-clock pair ``valve_simulator`` + ``pneumatic_cylinder``; with
  ``--backend can`` the CAN driver (``use_sim_time``) with the controller emulator, whose
  valve model advances on the simulation clock (``--clock sim``), and the cylinder in
  ``valve_lockstep_sim`` (``valve_source:=external``); ``--backend can --clock wall`` the
  earlier wall-clock loop (emulator in real time, as firmware, + ``pneumatic_cylinder``);
- ``flow_to_duty`` (one per valve), ``position_controller``, all with ``use_sim_time``
  in lockstep;
- ``valve_recorder`` writing every topic of the suite to ``RUN/bag_*`` (rosbag2, MCAP);
- with ``--live``, a Foxglove WebSocket server on 127.0.0.1 (``valve_bringup.live``);

shows what is running, moves the cylinder through a sequence of position goals while
printing what happens, stops every process (also on Ctrl-C), and writes
``RUN/report/report.md`` and ``RUN/report/report.json`` from the recorded bag. ``RUN`` is
a new directory per backend and run under ``demo_output/`` (or ``--out``).

In lockstep the demo drives the simulation's time: it holds it (``simulation/run_until``)
while it sends a goal and waits for the controller's acknowledgement, then lets it run
for the hold time; so every goal takes effect at the same simulated instant in every run,
and the same demo gives the same step metrics however loaded the computer is.
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor

__all__ = ['main', 'backend_processes', 'suite_processes', 'GOALS', 'DemoConfig']

#: Position goals [m] and how long each is held [s].
GOALS = ((0.020, 3.0), (0.060, 3.0), (0.040, 3.0), (0.080, 3.0), (0.030, 3.0))


@dataclass(frozen=True)
class DemoConfig:
    """What one demo run does."""

    backend: str = 'sim'
    out: Path = Path('demo_output')
    rate_hz: float = 1000.0
    effect_args: tuple[str, ...] = ()
    goals: tuple[tuple[float, float], ...] = GOALS
    clock: str = 'lockstep'            # lockstep | wall
    real_time_factor_max: float = 1.0  # lockstep pace cap; 0 = as fast as possible
    cylinder: str = 'single'           # single | double (lockstep only)
    live: bool = False                 # Foxglove WebSocket view on 127.0.0.1
    live_port: int = 8765
    #: Extra ``--ros-args`` of every flow_to_duty (e.g. ``-p map_file:=M -p params_file:=P``:
    #: the loop in service restarts it with an identified map); empty = its defaults.
    flow_to_duty_args: tuple[str, ...] = ()
    #: The physical valve's parameter set (YAML) where it differs from the suite's
    #: (config/valve.yaml): the CAN backend's emulated valve (``--params-file``) and the
    #: lockstep simulation's plant (``params_file``: the orifice the cylinder is filled
    #: through) carry it; flow_to_duty and the controller keep theirs. None = the suite's.
    #: Lockstep clock only.
    plant_params_file: Path | None = None
    #: The can backend's device: suite (the emulator) | canopen | j1939 | dbc (stand-ins).
    protocol: str = 'suite'

    @property
    def lockstep(self) -> bool:
        """Whether this run's simulation is in lockstep on simulation time."""
        return self.clock == 'lockstep'

    @property
    def valves(self) -> tuple[str, ...]:
        """Valve namespaces ('' = none)."""
        return ('cap', 'rod') if self.cylinder == 'double' else ('',)


def backend_processes(backend: str, *, rate_hz: float = 1000.0,
                      emulator_args: tuple[str, ...] = (),
                      protocol: str = 'suite') -> list[ProcessSpec]:
    """The processes that provide ``valve/state`` for a backend (``sim`` or ``can``)."""
    if backend == 'can' and protocol != 'suite':
        from valve_bringup.backend import device_backend_processes
        return device_backend_processes(protocol)
    if backend == 'sim':
        return [ProcessSpec('valve_simulator', [
            'valve_simulator', '--ros-args', '-p', f'publish_rate_hz:={rate_hz}'])]
    if backend == 'can':
        from valve_bringup.backend import can_backend_processes  # only when asked for
        return can_backend_processes(rate_hz=rate_hz, emulator_args=emulator_args)
    raise ValueError(f'unknown backend {backend!r}: expected "sim" or "can"')


def _plant_emulator_args(cfg: DemoConfig) -> tuple[str, ...]:
    """The emulator's ``--params-file`` when the physical valve is not the suite's."""
    return ('--params-file', str(cfg.plant_params_file)) if cfg.plant_params_file else ()


def _plant_gap_args(cfg: DemoConfig) -> tuple[str, ...]:
    """The cylinder integrates across the gap between two states of a slow device.

    The plant advances on each valve/state; a device that reports every 100 ms (J1939,
    the example board) leaves gaps the default limit (50 ms) would cut short, so the
    plant would run slower than the wall clock. The limit becomes 2.5 of its periods.
    """
    if cfg.backend != 'can' or cfg.protocol == 'suite':
        return ()
    from valve_bringup.backend import DEVICE_STATE_PERIOD_S
    gap_s = max(2.5 * DEVICE_STATE_PERIOD_S[cfg.protocol], 0.05)
    return ('--ros-args', '-p', f'max_advance_per_tick_s:={gap_s:g}')


def _topic(ns: str, topic: str) -> str:
    return f'{ns}/{topic}' if ns else topic


def recorded_topics(cfg: DemoConfig) -> list[str]:
    """What the recorder records: the suite's topics (per valve) and the simulation's."""
    from valve_model_pkg.interface import SUITE_TOPICS
    topics = []
    for name, msgtype in SUITE_TOPICS.items():
        spaces = cfg.valves if name.startswith('valve/') else ('',)
        topics += [f'{_topic(ns, name)}:{msgtype}' for ns in spaces]
    if cfg.lockstep:
        topics.append('simulation/real_time_factor:std_msgs/msg/Float64')
    return topics


def suite_processes(cfg: DemoConfig, bag: Path) -> list[ProcessSpec]:
    """Simulation or backend, flow_to_duty, plant, controller, recorder (in this order)."""
    recorder = ProcessSpec('valve_recorder', ['valve_recorder', '-o', str(bag),
                                              *recorded_topics(cfg)])
    if not cfg.lockstep:
        if cfg.plant_params_file:
            raise ValueError('a plant parameter set other than the suite\'s needs the '
                             'lockstep clock (its simulation carries the plant)')
        if cfg.backend == 'sim':
            backend = backend_processes('sim', rate_hz=cfg.rate_hz)
        else:
            backend = backend_processes(cfg.backend, rate_hz=cfg.rate_hz,
                                        emulator_args=cfg.effect_args, protocol=cfg.protocol)
        return backend + [
            ProcessSpec('flow_to_duty', ['flow_to_duty', *(
                ('--ros-args', *cfg.flow_to_duty_args) if cfg.flow_to_duty_args else ())]),
            ProcessSpec('pneumatic_cylinder', ['pneumatic_cylinder', *_plant_gap_args(cfg)]),
            ProcessSpec('position_controller', ['position_controller']),
            recorder,
        ]
    sim_time = ['-p', 'use_sim_time:=true', '-p', 'lockstep:=true']
    procs = []
    external = []
    if cfg.backend == 'can':
        # The valve runs in the controller emulator, stepped on the simulation clock
        # (valve_driver_pkg.emulator.lockstep); the driver stamps with simulation time.
        from valve_bringup.backend import can_backend_processes
        procs += can_backend_processes(
            rate_hz=cfg.rate_hz,
            emulator_args=('--clock', 'sim', '--step-s', f'{1.0 / cfg.rate_hz:g}',
                           *_plant_emulator_args(cfg), *cfg.effect_args),
            # The simulation stands still while the demo holds it and waits for the
            # controller on a busy computer: telemetry silence on the wall clock is then
            # no loss (the lockstep timeouts report a real one), so the driver's silence
            # limit is the lockstep timeout's, not 0.1 s.
            driver_args=('-p', 'use_sim_time:=true', '-p', 'telemetry_timeout_min_s:=10.0'))
        external = ['-p', 'valve_source:=external']
    procs.append(ProcessSpec('valve_lockstep_sim', [
        'valve_lockstep_sim', '--ros-args', '-p', 'start_paused:=true',
        '-p', f'real_time_factor_max:={float(cfg.real_time_factor_max)}',
        '-p', f'step_s:={1.0 / cfg.rate_hz}', '-p', f'cylinder:={cfg.cylinder}', *external,
        *(('-p', f'params_file:={cfg.plant_params_file}') if cfg.plant_params_file else ())]))
    for ns in cfg.valves:
        remap = ['-r', f'__ns:=/{ns}'] if ns else []
        procs.append(ProcessSpec(f'flow_to_duty{"_" + ns if ns else ""}', [
            'flow_to_duty', '--ros-args', *remap, *sim_time, *cfg.flow_to_duty_args]))
    double = ['-p', 'cylinder:=double'] if cfg.cylinder == 'double' else []
    procs.append(ProcessSpec('position_controller', [
        'position_controller', '--ros-args', *sim_time, *double]))
    procs.append(recorder)
    if cfg.live:
        procs.append(ProcessSpec('live_view', [
            sys.executable, '-m', 'valve_bringup.live', '--port', str(cfg.live_port),
            *[t.split(':')[0] for t in recorded_topics(cfg)]]))
    return procs


class _Watcher:
    """The demo's own rclpy node: sends goals, watches the suite's topics."""

    def __init__(self, valve_ns: str = '') -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import FluidPressure, JointState
        from std_msgs.msg import Float64
        from valve_msgs.msg import DutyCommand, FlowCommand

        from valve_msgs.msg import ValveState

        from valve_model_pkg.interface import (TOPIC_DUTY_COMMAND, TOPIC_FLOW_COMMAND,
                                               TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE,
                                               TOPIC_POSITION_GOAL, TOPIC_STATE,
                                               gauge_from_absolute)
        from valve_model_pkg.interface.ros import (COMMAND_QOS, JOINT_STATES_QOS,
                                                   PRESSURE_QOS, STATE_QOS)

        rclpy.init()
        self.probe = rclpy.create_node('valve_demo')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.probe)
        self.states = 0

        # valve/state only tells that the backend is up: 1 kHz in this process would take
        # CPU from the suite, so the subscription goes once the first state arrived.
        def on_state(msg: ValveState) -> None:
            self.states += 1
        self._state_sub = self.probe.create_subscription(ValveState, TOPIC_STATE, on_state,
                                                         STATE_QOS)
        self._goal_pub = self.probe.create_publisher(Float64, TOPIC_POSITION_GOAL,
                                                     COMMAND_QOS)
        self.position_m = math.nan
        self.pressure_pa = math.nan
        self.flow_cmd_sum = 0.0
        self.flow_cmd_n = 0
        self.duty_sum = 0.0
        self.duty_n = 0

        def on_joint(msg: JointState) -> None:
            if msg.position:
                self.position_m = msg.position[0]

        def on_pressure(msg: FluidPressure) -> None:
            self.pressure_pa = gauge_from_absolute(msg.fluid_pressure)

        self.flow_stamp_ns = -1   # of the newest flow command (lockstep: the tick answered)

        def on_flow(msg: FlowCommand) -> None:
            self.flow_cmd_sum += msg.mass_flow
            self.flow_cmd_n += 1
            self.flow_stamp_ns = max(self.flow_stamp_ns, msg.header.stamp.sec * 1_000_000_000
                                     + msg.header.stamp.nanosec)

        def on_duty(msg: DutyCommand) -> None:
            self.duty_sum += msg.duty
            self.duty_n += 1

        self.probe.create_subscription(JointState, TOPIC_JOINT_STATES, on_joint,
                                       JOINT_STATES_QOS)
        self.probe.create_subscription(FluidPressure, _topic(valve_ns, TOPIC_OUTPUT_PRESSURE),
                                       on_pressure, PRESSURE_QOS)
        self.probe.create_subscription(FlowCommand, _topic(valve_ns, TOPIC_FLOW_COMMAND),
                                       on_flow, COMMAND_QOS)
        self.probe.create_subscription(DutyCommand, _topic(valve_ns, TOPIC_DUTY_COMMAND),
                                       on_duty, COMMAND_QOS)

        # Lockstep: the simulation's clock, the controller's acknowledgement of a goal,
        # the simulation's real-time factor and its lockstep diagnostics.
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock
        from valve_model_pkg.interface import (TOPIC_CLOCK, TOPIC_DIAGNOSTICS,
                                               TOPIC_POSITION_SETPOINT,
                                               TOPIC_REAL_TIME_FACTOR, TOPIC_RUN_UNTIL)
        from valve_model_pkg.interface.ros import CLOCK_QOS, DIAGNOSTICS_QOS
        self.clock_ns = -1
        self.setpoint_m = math.nan
        self.rtf = math.nan
        self.sim_values: dict[str, str] = {}

        def on_clock(msg: Clock) -> None:
            self.clock_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec

        def on_setpoint(msg: Float64) -> None:
            self.setpoint_m = msg.data

        def on_rtf(msg: Float64) -> None:
            if msg.data > 0.0:
                self.rtf = msg.data

        def on_diag(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if 'lockstep simulation' in status.name:
                    self.sim_values = {kv.key: kv.value for kv in status.values}
        self.probe.create_subscription(Clock, TOPIC_CLOCK, on_clock, CLOCK_QOS)
        self.probe.create_subscription(Float64, TOPIC_POSITION_SETPOINT, on_setpoint,
                                       COMMAND_QOS)
        self.probe.create_subscription(Float64, TOPIC_REAL_TIME_FACTOR, on_rtf,
                                       COMMAND_QOS)
        self.probe.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, on_diag,
                                       DIAGNOSTICS_QOS)
        self._run_until_pub = self.probe.create_publisher(Float64, TOPIC_RUN_UNTIL,
                                                          COMMAND_QOS)

    def run_until(self, t_s: float) -> None:
        from std_msgs.msg import Float64
        self._run_until_pub.publish(Float64(data=float(t_s)))

    def subscribers(self, topic: str) -> int:
        """Subscriptions to ``topic`` in the graph, this watcher's own included."""
        return self.probe.count_subscribers(topic)

    def publishers(self, topic: str) -> int:
        return self.probe.count_publishers(topic)

    def goal(self, position_m: float) -> None:
        from std_msgs.msg import Float64
        self._goal_pub.publish(Float64(data=float(position_m)))

    def stop_watching_state(self) -> None:
        if self._state_sub is not None:
            self.probe.destroy_subscription(self._state_sub)
            self._state_sub = None

    def reset(self) -> None:
        self.flow_cmd_sum = self.duty_sum = 0.0
        self.flow_cmd_n = self.duty_n = 0

    def spin_for(self, seconds: float, sup: Supervisor) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)
            sup.check_alive()

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.probe.destroy_node()
        rclpy.try_shutdown()


def _step_line(w: _Watcher, goal_m: float, extra: str = '') -> str:
    flow_cmd = w.flow_cmd_sum / w.flow_cmd_n if w.flow_cmd_n else math.nan
    duty = w.duty_sum / w.duty_n if w.duty_n else math.nan
    return (f'{goal_m * 1e3:6.1f}mm {w.position_m * 1e3:7.2f}mm '
            f'{(w.position_m - goal_m) * 1e3:+6.2f} {w.pressure_pa / 1e5:6.2f}bar '
            f'{flow_cmd * 1e3:6.3f}g/s {duty * 100:5.1f}%{extra}')


#: Simulated time before the first goal [s]: the suite settles at the initial setpoint.
PRE_ROLL_S = 0.5


def _drive_lockstep(sup: Supervisor, cfg: DemoConfig) -> tuple[int, dict]:
    """Drive the held simulation: goal, acknowledgement, run for the hold time; repeat."""
    w = _Watcher(cfg.valves[0])
    info: dict = {'clock': 'simulation (lockstep)',
                  'real_time_factor_max': cfg.real_time_factor_max or None}
    try:
        sup.say('waiting for the simulation and for every node to subscribe ...')
        from valve_model_pkg import interface as itf
        state_topic = '/' + _topic(cfg.valves[0], itf.TOPIC_STATE)
        needs = [('/' + itf.TOPIC_JOINT_STATES, 2),        # controller + recorder
                 ('/' + itf.TOPIC_POSITION_GOAL, 2),       # controller + recorder
                 ('/' + itf.TOPIC_POSITION_SETPOINT, 2)]   # this watcher + recorder: the
        # report finds the steps from the recorded setpoints, the first one included
        for ns in cfg.valves:
            needs += [('/' + _topic(ns, itf.TOPIC_FLOW_COMMAND), 2),  # flow_to_duty + recorder
                      ('/' + _topic(ns, itf.TOPIC_OUTPUT_PRESSURE), 2),
                      ('/' + _topic(ns, itf.TOPIC_DUTY_COMMAND), 2)]  # simulation + recorder
        publishers = []
        if cfg.backend == 'can':
            # the valve is the emulator's, on /clock: the simulation reads its state (and
            # the recorder); the driver and the emulator's clock bridge take duty commands.
            # The counts include this watcher's own subscriptions (duty: simulation,
            # recorder, emulator, driver, watcher), and the driver's /clock subscription
            # exists before it is configured: without its state publisher (made when it
            # is configured, then it activates) the run could start before the driver was
            # on the bus and lose the first step's state (a 10 s lockstep timeout).
            needs += [(state_topic, 2), ('/' + itf.TOPIC_DUTY_COMMAND, 5),
                      (itf.TOPIC_CLOCK, 5)]  # emulator, driver, controller, f2d, demo
            publishers.append((state_topic, 1))                       # the driver
        else:
            needs.append((state_topic, 1))                            # recorder
        deadline = time.monotonic() + 120.0
        while w.clock_ns < 0 or any(w.subscribers(t) < n for t, n in needs) \
                or any(w.publishers(t) < n for t, n in publishers):
            w.spin_for(0.1, sup)
            if time.monotonic() > deadline:
                missing = [t for t, n in needs if w.subscribers(t) < n] + \
                    [f'{t} (publisher)' for t, n in publishers if w.publishers(t) < n]
                sup.say(f'the suite did not come up within 120 s (waiting for {missing}): '
                        'giving up')
                return 1, info
        w.stop_watching_state()
        w.spin_for(0.5, sup)  # let the subscriptions match the publishers
        sup.say('the suite is up. What is running:\n' + sup.table())
        cap = 'as fast as possible' if not cfg.real_time_factor_max \
            else f'at most {cfg.real_time_factor_max:g} x real time'
        sup.say(f'simulation time in lockstep with the controller, {cap}')
        wall0 = time.monotonic()
        target = _run_to(w, sup, PRE_ROLL_S)
        sup.say(f'{"goal":>8} {"position":>9} {"error":>7} {"chamber":>9} {"flow cmd":>9} '
                f'{"duty":>6}  sim time, real-time factor')
        for goal_m, hold_s in cfg.goals:
            sup.say(f'moving the piston to {goal_m * 1e3:.0f} mm and holding {hold_s:g} s '
                    '(simulated)')
            w.goal(goal_m)
            deadline = time.monotonic() + 30.0
            last_sent = time.monotonic()
            while w.setpoint_m != goal_m:  # the controller's acknowledgement
                w.spin_for(0.02, sup)
                if time.monotonic() - last_sent > 1.0:
                    # lost or not yet matched (the readiness counts can be met by other
                    # subscribers, e.g. the live view): say it again (the same goal)
                    w.goal(goal_m)
                    last_sent = time.monotonic()
                if time.monotonic() > deadline:
                    sup.say('the controller did not acknowledge the goal within 30 s')
                    return 1, info
            w.reset()
            target = _run_to(w, sup, target + hold_s)
            sup.say(_step_line(w, goal_m, f'  t={w.clock_ns * 1e-9:6.2f}s rtf {w.rtf:4.2f}'))
        wall = time.monotonic() - wall0
        info['real_time_factor'] = target / wall if wall > 0 else None
        info['simulated_s'], info['wall_s'] = target, wall
        w.spin_for(1.2, sup)  # the simulation's last diagnostics
        info['lockstep_timeouts'] = int(w.sim_values.get('lockstep_timeouts', '0'))
        info['last_lockstep_timeout'] = w.sim_values.get('last_lockstep_timeout', '')
        sup.say(f'real-time factor of the run: {info["real_time_factor"]:.2f} '
                f'({target:.2f} s simulated in {wall:.2f} s); lockstep timeouts: '
                f'{info["lockstep_timeouts"]}')
        return 0, info
    finally:
        w.close()


def _run_to(w: _Watcher, sup: Supervisor, t_s: float) -> float:
    """Let the held simulation run to ``t_s`` (rounded to 1 ms) and wait until it is there."""
    t_s = round(t_s, 3)
    w.run_until(t_s)
    target_ns = int(round(t_s * 1e9))
    last_sent = time.monotonic()
    while w.clock_ns < target_ns:
        w.spin_for(0.02, sup)
        if time.monotonic() - last_sent > 1.0:
            w.run_until(t_s)  # lost or not yet matched: say it again (idempotent)
            last_sent = time.monotonic()
    # ... and until the controller has answered the tick it is held at: a goal sent before
    # that answer took effect at this tick, one sent after it at the next, as the messages
    # fell (two loops' after runs parted at the third goal, 2026-11-26). A controller
    # without feedback never answers: at most 2 s.
    deadline = time.monotonic() + 2.0
    while w.flow_stamp_ns < target_ns and time.monotonic() < deadline:
        w.spin_for(0.01, sup)
    return t_s


def _drive(sup: Supervisor, cfg: DemoConfig) -> tuple[int, dict]:
    if cfg.lockstep:
        return _drive_lockstep(sup, cfg)
    w = _Watcher()
    info: dict = {'clock': 'wall'}
    try:
        sup.say('waiting for valve/state and cylinder/joint_states ...')
        deadline = time.monotonic() + 60.0
        while w.states == 0 or math.isnan(w.position_m):
            w.spin_for(0.1, sup)
            if time.monotonic() > deadline:
                sup.say('the suite did not come up within 60 s: giving up')
                return 1, info
        w.stop_watching_state()
        w.spin_for(2.0, sup)  # let the recorder discover and subscribe every topic
        sup.say('the suite is up. What is running:\n' + sup.table())
        sup.say(f'{"goal":>8} {"position":>9} {"error":>7} {"chamber":>9} {"flow cmd":>9} '
                f'{"duty":>6}')
        wall0 = time.monotonic()
        for goal_m, hold_s in cfg.goals:
            sup.say(f'moving the piston to {goal_m * 1e3:.0f} mm and holding {hold_s:g} s')
            w.goal(goal_m)
            w.reset()
            w.spin_for(hold_s, sup)
            sup.say(_step_line(w, goal_m))
        info['real_time_factor'] = 1.0  # wall clock: simulated and real time are one
        info['wall_s'] = time.monotonic() - wall0
        return 0, info
    finally:
        w.close()


def run_directory(cfg: DemoConfig, out_given: bool) -> Path:
    """The run's own directory: ``--out`` as given, else a new one per backend and run."""
    if out_given:
        return cfg.out
    label = cfg.backend + ('_double' if cfg.cylinder == 'double' else '') + \
        ('' if cfg.lockstep else '_wall')
    base = cfg.out / f'{label}_{time.strftime("%Y%m%d-%H%M%S")}'
    run_dir, n = base, 1
    while run_dir.exists():  # two runs in one second: never overwrite
        n += 1
        run_dir = base.with_name(f'{base.name}_{n}')
    return run_dir


def run(cfg: DemoConfig, out_given: bool = True) -> int:
    """Run the demo; returns the exit code."""
    run_dir = run_directory(cfg, out_given)
    if (run_dir / 'report').exists():
        print(f'valve_demo: error: {run_dir} already holds a run ({run_dir / "report"}); '
              'give another --out, or none for a new directory per run', file=sys.stderr)
        return 2
    run_dir.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime('%Y%m%d-%H%M%S')
    bag = run_dir / f'bag_{cfg.backend}_{stamp}'
    code = 1
    info: dict = {}
    with Supervisor() as sup:
        sup.say(f'valve suite demo: backend {cfg.backend}, cylinder {cfg.cylinder}, clock '
                f'{"simulation (lockstep)" if cfg.lockstep else "wall"}, ROS_DOMAIN_ID='
                f'{os.environ.get("ROS_DOMAIN_ID", "0")}, discovery '
                f'{os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]}, output {run_dir}')
        if cfg.backend == 'can' and cfg.lockstep:
            sup.say('CAN backend on simulation time: the controller emulator\'s valve model '
                    'advances on /clock (valve_controller_emulator --clock sim), the driver '
                    'runs with use_sim_time, the cylinder is in valve_lockstep_sim')
        elif cfg.backend == 'can':
            sup.say('the CAN backend runs on wall-clock time: the controller emulator stands '
                    'in for firmware that runs in real time (see the report)')
        try:
            for spec in suite_processes(cfg, bag):
                sup.start(spec)
            if cfg.live:
                sup.say(f'live view: Foxglove WebSocket on ws://127.0.0.1:{cfg.live_port} '
                        '(Foxglove: Open connection -> Foxglove WebSocket; layouts in '
                        'layouts/)')
            code, info = _drive(sup, cfg)
        except KeyboardInterrupt:
            sup.say('interrupted: stopping all processes')
            code = 130
        except ChildExited as err:
            sup.say(f'error: {err}')
            code = 1
        sup.say('stopping (recorder first, so the bag is closed) ...')
        codes = sup.stop()
        sup.say('stopped: ' + ', '.join(f'{n} exit {c}' for n, c in codes.items()))
    if code == 0:
        from valve_model_pkg.cli.report import write_report
        info.update(backend=cfg.backend, cylinder=cfg.cylinder,
                    exit_codes={n: c for n, c in codes.items()})
        if cfg.backend == 'can' and cfg.lockstep:
            info['clock_note'] = (
                'simulation time: the controller emulator advances its valve model on the '
                'simulation clock, one telemetry frame per 1 ms step, and waits at each '
                'control tick for that tick\'s command on the bus; valve/state comes '
                'through the CAN driver (use_sim_time) at one message per simulated step')
        elif cfg.backend == 'can':
            info['clock_note'] = (
                'wall clock: the controller emulator runs the valve model in real time, as '
                'the firmware it stands in for does, and the CAN driver stamps telemetry '
                'with wall-clock time; the loop spans emulator, driver, plant, flow_to_duty '
                'and controller processes, so scheduling delays on a loaded computer become '
                'plant delays and this run is not reproducible step for step')
        report = write_report(bag, run_dir / 'report',
                              title=f'valve suite demo ({cfg.backend} backend, '
                              f'{cfg.cylinder} cylinder, {info.get("clock", "wall")} clock)',
                              run_info=info, valve=cfg.valves[0])
        print(f'[{"demo":>18}] bag: {bag}')
        print(f'[{"demo":>18}] report: {report} (and report.json)')
        print(report.read_text())
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_demo``."""
    parser = argparse.ArgumentParser(prog='valve_demo', description=__doc__.split('\n')[0])
    parser.add_argument('--backend', choices=('sim', 'can'), default='sim',
                        help='valve/state from the simulator or the CAN driver + emulator')
    parser.add_argument('--clock', choices=('lockstep', 'wall'), default='lockstep',
                        help='lockstep: simulation time, the simulation waits for the '
                        'controller (default; with --backend can the emulator\'s valve '
                        'advances on /clock); wall: separate processes on wall-clock time')
    parser.add_argument('--protocol', choices=('suite', 'canopen', 'j1939', 'dbc'),
                        default='suite', help='(--backend can) what the driver speaks: the '
                        'suite\'s emulator, or a stand-in CANopen / J1939 / DBC device '
                        '(wall clock)')
    parser.add_argument('--as-fast-as-possible', action='store_true',
                        help='(lockstep) do not cap the real-time factor at 1')
    parser.add_argument('--cylinder', choices=('single', 'double'), default='single',
                        help='single-acting cylinder with one valve, or double-acting with '
                        'one 3/2 valve per chamber (lockstep only)')
    parser.add_argument('--live', action='store_true',
                        help='serve the suite\'s topics on a Foxglove WebSocket (127.0.0.1)')
    parser.add_argument('--live-port', type=int, default=8765, help='port of the live view')
    parser.add_argument('--hold', type=float, default=None, metavar='S',
                        help='hold each goal S seconds (default 3; tests use less)')
    parser.add_argument('--rate', type=float, default=1000.0, help='valve/state rate [Hz]')
    parser.add_argument('-o', '--out', type=Path, default=None,
                        help='directory of this run (bag and report); default: a new '
                        'demo_output/BACKEND_DATE-TIME per run')
    parser.add_argument('--effect', action='append', default=[], metavar='NAME',
                        help='(can backend) the emulator\'s valve carries this physical '
                        'effect, which the nominal model lacks')
    parser.add_argument('--quick', action='store_true',
                        help='shorter goal sequence (for tests)')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    effect_args = tuple(a for name in args.effect for a in ('--effect', name))
    if effect_args and args.backend != 'can':
        parser.error('--effect needs --backend can (the emulator carries the effect)')
    if args.cylinder == 'double' and (args.backend != 'sim' or args.clock != 'lockstep'):
        # the CAN backend has one controller (emulator) on its bus: one valve
        parser.error('--cylinder double needs the lockstep simulation (--backend sim '
                     '--clock lockstep)')
    if args.hold is not None and not 0.1 <= args.hold <= 600.0:
        parser.error(f'--hold {args.hold!r}: expected 0.1 .. 600 s')
    if not 1 <= args.live_port <= 65535:
        parser.error(f'--live-port {args.live_port!r}: expected 1 .. 65535')
    goals = tuple((g, 2.0) for g, _ in GOALS[:3]) if args.quick else GOALS
    if args.hold is not None:
        goals = tuple((g, args.hold) for g, _ in goals)

    # Ctrl-C / SIGTERM: raise in the main thread so the supervisor's context exit stops all.
    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _interrupt)
    if args.protocol != 'suite':   # the stand-in devices run on the wall clock
        if args.backend != 'can':
            parser.error('--protocol needs --backend can')
        args.clock = 'wall'
    cfg = DemoConfig(args.backend, args.out or Path('demo_output'), args.rate, effect_args,
                     goals, clock=args.clock, protocol=args.protocol,
                     real_time_factor_max=0.0 if args.as_fast_as_possible else 1.0,
                     cylinder=args.cylinder, live=args.live, live_port=args.live_port)
    return run(cfg, out_given=args.out is not None)


if __name__ == '__main__':
    sys.exit(main())
