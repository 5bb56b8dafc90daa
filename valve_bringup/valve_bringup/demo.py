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
  wall-clock loop (emulator in real time, as firmware, + ``pneumatic_cylinder``);
- ``flow_to_duty`` (one per valve), ``position_controller``, all with ``use_sim_time``
  in lockstep;
- ``valve_recorder`` writing every topic of the suite to ``RUN/bag_*`` (rosbag2, MCAP);
- with ``--live``, a Foxglove WebSocket server on 127.0.0.1 (``valve_bringup.live``);

shows what is running, moves the cylinder through a sequence of position goals
(:data:`valve_model_pkg.pneumatics.goals.DEMO_GOALS`) while printing what happens, stops
every process (also on Ctrl-C), and writes
``RUN/report/report.md`` and ``RUN/report/report.json`` from the recorded bag
(:func:`valve_model_pkg.analysis.write_run_report`; report.json also carries the goals,
the exit codes and the machine's load). ``RUN`` is a new directory per backend and run
under ``demo_output/`` (or ``--out``).

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
from typing import NamedTuple

from valve_bringup.backend import (DEVICE_STATE_PERIOD_S, can_backend_processes,
                                   device_backend_processes)
from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor
from valve_bringup.watcher import (DISCOVERY_WAIT_S, DemoWatcher, suite_topics_in_use,
                                   valve_topic)
from valve_model_pkg.analysis import write_run_report
from valve_model_pkg.interface import (SUITE_TOPICS, TOPIC_CLOCK, TOPIC_DUTY_COMMAND,
                                       TOPIC_FLOW_COMMAND, TOPIC_JOINT_STATES,
                                       TOPIC_OUTPUT_PRESSURE, TOPIC_POSITION_GOAL,
                                       TOPIC_POSITION_SETPOINT, TOPIC_STATE)
from valve_model_pkg.pneumatics.goals import (DEMO_GOALS, DEMO_QUICK_GOALS, PRE_ROLL_S,
                                              GoalSequence, with_hold)

__all__ = ['main', 'run', 'DemoConfig', 'backend_processes', 'suite_processes',
           'recorded_topics', 'lockstep_readiness', 'Readiness', 'demo_goals',
           'run_directory']

#: How long the suite may take to come up [s of wall time].
SUITE_UP_TIMEOUT_S = 120.0
#: How long the controller may take to acknowledge a goal [s of wall time].
GOAL_ACK_TIMEOUT_S = 30.0
#: How long the controller chain may take to answer the tick the simulation is held at
#: [s of wall time].
TICK_ANSWER_TIMEOUT_S = 2.0


def demo_goals(quick: bool = False, hold_s: float | None = None) -> GoalSequence:
    """The goals of ``valve_demo [--quick] [--hold S]``: the demo's, each held ``hold_s``."""
    goals = DEMO_QUICK_GOALS if quick else DEMO_GOALS
    return goals if hold_s is None else with_hold(goals, hold_s)


@dataclass(frozen=True)
class DemoConfig:
    """What one demo run does."""

    backend: str = 'sim'
    out: Path = Path('demo_output')
    rate_hz: float = 1000.0
    effect_args: tuple[str, ...] = ()
    goals: GoalSequence = DEMO_GOALS
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
    #: Discovery time for another suite on this ROS domain before the run starts [s]
    #: (found: the run is refused); 0 skips the check.
    domain_check_s: float = DISCOVERY_WAIT_S

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
        return device_backend_processes(protocol)
    if backend == 'sim':
        return [ProcessSpec('valve_simulator', [
            'valve_simulator', '--ros-args', '-p', f'publish_rate_hz:={rate_hz}'])]
    if backend == 'can':
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
    gap_s = max(2.5 * DEVICE_STATE_PERIOD_S[cfg.protocol], 0.05)
    return ('--ros-args', '-p', f'max_advance_per_tick_s:={gap_s:g}')


def recorded_topics(cfg: DemoConfig) -> list[str]:
    """What the recorder records: the suite's topics (per valve) and the simulation's."""
    topics = []
    for name, msgtype in SUITE_TOPICS.items():
        spaces = cfg.valves if name.startswith('valve/') else ('',)
        topics += [f'{valve_topic(ns, name)}:{msgtype}' for ns in spaces]
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


def _run_to(w: DemoWatcher, sup: Supervisor, t_s: float) -> float:
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
    # ... and until the controller chain has answered the tick it is held at (its flow
    # command stamped with it), so that the next goal takes effect at the next tick in
    # every run, whenever the controller reads it. A controller without feedback never
    # answers: at most TICK_ANSWER_TIMEOUT_S.
    deadline = time.monotonic() + TICK_ANSWER_TIMEOUT_S
    while w.flow_stamp_ns < target_ns and time.monotonic() < deadline:
        w.spin_for(0.01, sup)
    return t_s


class Readiness(NamedTuple):
    """What a lockstep run waits for before it starts: (topic, least count) pairs."""

    subscribers: list[tuple[str, int]]
    publishers: list[tuple[str, int]]


def lockstep_readiness(cfg: DemoConfig) -> Readiness:
    """The subscriptions and publishers every node of a lockstep run has made.

    The counts include the demo's own subscriptions. The setpoint needs the demo and the
    recorder: the report finds the steps from the recorded setpoints, the first included.
    With the CAN backend the valve is the emulator's, on /clock: the simulation and the
    recorder read its state; the driver and the emulator's clock bridge take duty
    commands (simulation, recorder, emulator, driver, demo); /clock goes to the emulator,
    driver, controller, flow_to_duty and demo. The driver's /clock subscription exists
    before it is configured, so its state publisher (made when it is configured, then it
    activates) is waited for too: without it the run could start before the driver is on
    the bus and lose the first step's state.
    """
    state_topic = '/' + valve_topic(cfg.valves[0], TOPIC_STATE)
    needs = [('/' + TOPIC_JOINT_STATES, 2),        # controller + recorder
             ('/' + TOPIC_POSITION_GOAL, 2),       # controller + recorder
             ('/' + TOPIC_POSITION_SETPOINT, 2)]   # demo + recorder
    for ns in cfg.valves:
        needs += [('/' + valve_topic(ns, TOPIC_FLOW_COMMAND), 2),   # flow_to_duty + recorder
                  ('/' + valve_topic(ns, TOPIC_OUTPUT_PRESSURE), 2),
                  ('/' + valve_topic(ns, TOPIC_DUTY_COMMAND), 2)]   # simulation + recorder
    publishers = []
    if cfg.backend == 'can':
        needs += [(state_topic, 2), ('/' + TOPIC_DUTY_COMMAND, 5), (TOPIC_CLOCK, 5)]
        publishers.append((state_topic, 1))                       # the driver
    else:
        needs.append((state_topic, 1))                            # recorder
    return Readiness(needs, publishers)


def _wait_until_up(w: DemoWatcher, sup: Supervisor, ready: Readiness) -> bool:
    """Spin until the simulation's clock runs, the graph has every node's endpoints and the
    recorder's subscriptions have matched every publisher of them (the graph lists a
    reader before the writers match it: a run started then loses its first messages)."""
    def missing() -> list[str]:
        graph = [t for t, n in ready.subscribers if w.subscribers(t) < n] + \
            [f'{t} (publisher)' for t, n in ready.publishers if w.publishers(t) < n]
        return graph or w.recorder_unmatched([t for t, _ in ready.subscribers])
    deadline = time.monotonic() + SUITE_UP_TIMEOUT_S
    while w.clock_ns < 0 or missing():
        w.spin_for(0.1, sup)
        if time.monotonic() > deadline:
            sup.say(f'the suite did not come up within {SUITE_UP_TIMEOUT_S:g} s (waiting for '
                    f'{missing()}): giving up')
            return False
    return True


def _send_goal(w: DemoWatcher, sup: Supervisor, goal_m: float) -> bool:
    """Send a goal and wait for the controller's acknowledgement (its setpoint).

    A goal lost or not yet matched (the readiness counts can be met by other subscribers,
    e.g. the live view) is said again, the same goal, every second.
    """
    w.goal(goal_m)
    deadline = time.monotonic() + GOAL_ACK_TIMEOUT_S
    last_sent = time.monotonic()
    while w.setpoint_m != goal_m:
        w.spin_for(0.02, sup)
        if time.monotonic() - last_sent > 1.0:
            w.goal(goal_m)
            last_sent = time.monotonic()
        if time.monotonic() > deadline:
            sup.say(f'the controller did not acknowledge the goal within '
                    f'{GOAL_ACK_TIMEOUT_S:g} s')
            return False
    return True


def _drive_lockstep(sup: Supervisor, cfg: DemoConfig) -> tuple[int, dict]:
    """Drive the held simulation: goal, acknowledgement, run for the hold time; repeat."""
    w = DemoWatcher(cfg.valves[0])
    info: dict = {'clock': 'simulation (lockstep)',
                  'real_time_factor_max': cfg.real_time_factor_max or None}
    try:
        sup.say('waiting for the simulation and for every node to subscribe ...')
        if not _wait_until_up(w, sup, lockstep_readiness(cfg)):
            return 1, info
        w.stop_watching_state()
        w.spin_for(0.5, sup)  # let the subscriptions match the publishers
        sup.say('the suite is up. What is running:\n' + sup.table())
        cap = 'as fast as possible' if not cfg.real_time_factor_max \
            else f'at most {cfg.real_time_factor_max:g} x real time'
        sup.say(f'simulation time in lockstep with the controller, {cap}')
        wall0 = time.monotonic()
        target = _run_to(w, sup, PRE_ROLL_S)
        # each goal takes effect at the next tick after the held time it is acknowledged at
        info['goal_times_s'] = []
        sup.say(f'{"goal":>8} {"position":>9} {"error":>7} {"chamber":>9} {"flow cmd":>9} '
                f'{"duty":>6}  sim time, real-time factor')
        for goal_m, hold_s in cfg.goals:
            sup.say(f'moving the piston to {goal_m * 1e3:.0f} mm and holding {hold_s:g} s '
                    '(simulated)')
            if not _send_goal(w, sup, goal_m):
                return 1, info
            info['goal_times_s'].append(target)
            w.reset()
            target = _run_to(w, sup, target + hold_s)
            sup.say(w.step_line(goal_m, f'  t={w.clock_ns * 1e-9:6.2f}s rtf {w.rtf:4.2f}'))
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


def _drive_wall(sup: Supervisor, cfg: DemoConfig) -> tuple[int, dict]:
    """Drive the suite on wall-clock time: goal, hold; repeat."""
    w = DemoWatcher()
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
            sup.say(w.step_line(goal_m))
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
    busy = suite_topics_in_use(cfg.domain_check_s)
    if busy:
        print(f'valve_demo: error: ROS_DOMAIN_ID {os.environ.get("ROS_DOMAIN_ID", "0")} '
              f'already carries the valve state of another suite ({", ".join(busy[:3])}'
              f'{", ..." if busy[3:] else ""})'
              '; another demo or suite runs on this domain: stop it, or run this one with '
              'its own ROS_DOMAIN_ID=N', file=sys.stderr)
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
            drive = _drive_lockstep if cfg.lockstep else _drive_wall
            code, info = drive(sup, cfg)
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
        _write_report(cfg, bag, run_dir, info, codes)
    return code


#: What the report says of each backend's clock (a lockstep run on the simulator needs no
#: note: the report's clock line says it).
_CLOCK_NOTES = {
    ('can', True): (
        'simulation time: the controller emulator advances its valve model on the '
        'simulation clock, one telemetry frame per 1 ms step, and waits at each '
        'control tick for that tick\'s command on the bus; valve/state comes '
        'through the CAN driver (use_sim_time) at one message per simulated step'),
    ('can', False): (
        'wall clock: the controller emulator runs the valve model in real time, as '
        'the firmware it stands in for does, and the CAN driver stamps telemetry '
        'with wall-clock time; the loop spans emulator, driver, plant, flow_to_duty '
        'and controller processes, so scheduling delays on a loaded computer become '
        'plant delays and this run is not reproducible step for step'),
}


def _write_report(cfg: DemoConfig, bag: Path, run_dir: Path, info: dict,
                  codes: dict[str, int | None]) -> None:
    """``RUN/report/`` from the bag and what the run knows (printed as well)."""
    info.update(backend=cfg.backend, cylinder=cfg.cylinder,
                exit_codes={n: c for n, c in codes.items()},
                goals=[{'position_mm': g * 1e3, 'hold_s': h} for g, h in cfg.goals],
                pre_roll_s=PRE_ROLL_S if cfg.lockstep else None, rate_hz=cfg.rate_hz,
                effect_args=list(cfg.effect_args))
    note = _CLOCK_NOTES.get((cfg.backend, cfg.lockstep))
    if note:
        info['clock_note'] = note
    report = write_run_report(bag, run_dir / 'report',
                              title=f'valve suite demo ({cfg.backend} backend, '
                              f'{cfg.cylinder} cylinder, {info.get("clock", "wall")} clock)',
                              run_info=info, valve=cfg.valves[0]).markdown
    print(f'[{"demo":>18}] bag: {bag}')
    print(f'[{"demo":>18}] report: {report} (and report.json)')
    print(report.read_text())


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
    parser.add_argument('--domain-check', type=float, default=DISCOVERY_WAIT_S, metavar='S',
                        help='listen this long for another suite on this ROS_DOMAIN_ID and '
                        f'refuse to start beside it (default {DISCOVERY_WAIT_S:g} s; 0: no '
                        'check)')
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
    if not 0.0 <= args.domain_check <= 60.0:
        parser.error(f'--domain-check {args.domain_check!r}: expected 0 .. 60 s')
    if not 1 <= args.live_port <= 65535:
        parser.error(f'--live-port {args.live_port!r}: expected 1 .. 65535')
    goals = demo_goals(args.quick, args.hold)

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
                     cylinder=args.cylinder, live=args.live, live_port=args.live_port,
                     domain_check_s=args.domain_check)
    return run(cfg, out_given=args.out is not None)


if __name__ == '__main__':
    sys.exit(main())
