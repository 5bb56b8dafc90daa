"""valve_demo: a user's day with the suite, as separate processes, ending with a report.

This is what ``make demo`` runs. It starts, each as its own process (the ``launch``
package is not in the ROS 2 wheels; users with a full ROS install have
``ros2 launch valve_bringup valve_suite.launch.py``):

- the valve backend: ``valve_simulator`` (``--backend sim``) or the CAN driver with the
  controller emulator (``--backend can``),
- ``flow_to_duty``, ``pneumatic_cylinder``, ``position_controller``,
- ``valve_recorder`` writing every topic of the suite to ``OUT/bag`` (rosbag2, MCAP),

shows what is running, moves the cylinder through a sequence of position goals while
printing what happens, stops every process (also on Ctrl-C), and writes
``OUT/report/report.md`` with plots from the recorded bag.
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

__all__ = ['main', 'backend_processes', 'suite_processes', 'GOALS']

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


def backend_processes(backend: str, *, rate_hz: float = 1000.0,
                      emulator_args: tuple[str, ...] = ()) -> list[ProcessSpec]:
    """The processes that provide ``valve/state`` for a backend (``sim`` or ``can``)."""
    if backend == 'sim':
        return [ProcessSpec('valve_simulator', [
            'valve_simulator', '--ros-args', '-p', f'publish_rate_hz:={rate_hz}'])]
    if backend == 'can':
        from valve_bringup.backend import can_backend_processes  # only when asked for
        return can_backend_processes(rate_hz=rate_hz, emulator_args=emulator_args)
    raise ValueError(f'unknown backend {backend!r}: expected "sim" or "can"')


def suite_processes(cfg: DemoConfig, bag: Path) -> list[ProcessSpec]:
    """Backend, flow_to_duty, plant, controller, recorder (started in this order)."""
    return backend_processes(cfg.backend, rate_hz=cfg.rate_hz,
                             emulator_args=cfg.effect_args) + [
        ProcessSpec('flow_to_duty', ['flow_to_duty']),
        ProcessSpec('pneumatic_cylinder', ['pneumatic_cylinder']),
        ProcessSpec('position_controller', ['position_controller']),
        ProcessSpec('valve_recorder', ['valve_recorder', '-o', str(bag)]),
    ]


class _Watcher:
    """The demo's own rclpy node: sends goals, watches the suite's topics."""

    def __init__(self) -> None:
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

        def on_flow(msg: FlowCommand) -> None:
            self.flow_cmd_sum += msg.mass_flow
            self.flow_cmd_n += 1

        def on_duty(msg: DutyCommand) -> None:
            self.duty_sum += msg.duty
            self.duty_n += 1

        self.probe.create_subscription(JointState, TOPIC_JOINT_STATES, on_joint,
                                       JOINT_STATES_QOS)
        self.probe.create_subscription(FluidPressure, TOPIC_OUTPUT_PRESSURE, on_pressure,
                                       PRESSURE_QOS)
        self.probe.create_subscription(FlowCommand, TOPIC_FLOW_COMMAND, on_flow, COMMAND_QOS)
        self.probe.create_subscription(DutyCommand, TOPIC_DUTY_COMMAND, on_duty, COMMAND_QOS)

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


def _drive(sup: Supervisor, cfg: DemoConfig) -> int:
    w = _Watcher()
    try:
        sup.say('waiting for valve/state and cylinder/joint_states ...')
        deadline = time.monotonic() + 60.0
        while w.states == 0 or math.isnan(w.position_m):
            w.spin_for(0.1, sup)
            if time.monotonic() > deadline:
                sup.say('the suite did not come up within 60 s: giving up')
                return 1
        w.stop_watching_state()
        w.spin_for(2.0, sup)  # let the recorder discover and subscribe every topic
        sup.say('the suite is up. What is running:\n' + sup.table())
        sup.say(f'{"goal":>8} {"position":>9} {"error":>7} {"chamber":>9} {"flow cmd":>9} '
                f'{"duty":>6}')
        for goal_m, hold_s in cfg.goals:
            sup.say(f'moving the piston to {goal_m * 1e3:.0f} mm and holding {hold_s:g} s')
            w.goal(goal_m)
            w.reset()
            w.spin_for(hold_s, sup)
            flow_cmd = w.flow_cmd_sum / w.flow_cmd_n if w.flow_cmd_n else math.nan
            duty = w.duty_sum / w.duty_n if w.duty_n else math.nan
            sup.say(f'{goal_m * 1e3:6.1f}mm {w.position_m * 1e3:7.2f}mm '
                    f'{(w.position_m - goal_m) * 1e3:+6.2f} {w.pressure_pa / 1e5:6.2f}bar '
                    f'{flow_cmd * 1e3:6.3f}g/s {duty * 100:5.1f}%')
        return 0
    finally:
        w.close()


def run(cfg: DemoConfig) -> int:
    """Run the demo; returns the exit code."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime('%Y%m%d-%H%M%S')
    bag = cfg.out / f'bag_{cfg.backend}_{stamp}'
    code = 1
    with Supervisor() as sup:
        sup.say(f'valve suite demo: backend {cfg.backend}, ROS_DOMAIN_ID='
                f'{os.environ.get("ROS_DOMAIN_ID", "0")}, discovery '
                f'{os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]}, output {cfg.out}')
        try:
            for spec in suite_processes(cfg, bag):
                sup.start(spec)
            code = _drive(sup, cfg)
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
        report = write_report(bag, cfg.out / 'report',
                              title=f'valve suite demo ({cfg.backend} backend)')
        print(f'[{"demo":>18}] bag: {bag}')
        print(f'[{"demo":>18}] report: {report}')
        print(report.read_text())
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_demo``."""
    parser = argparse.ArgumentParser(prog='valve_demo', description=__doc__.split('\n')[0])
    parser.add_argument('--backend', choices=('sim', 'can'), default='sim',
                        help='valve/state from the simulator or the CAN driver + emulator')
    parser.add_argument('--rate', type=float, default=1000.0, help='valve/state rate [Hz]')
    parser.add_argument('-o', '--out', type=Path, default=Path('demo_output'),
                        help='directory for the bag and the report')
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
    goals = tuple((g, 2.0) for g, _ in GOALS[:3]) if args.quick else GOALS

    # Ctrl-C / SIGTERM: raise in the main thread so the supervisor's context exit stops all.
    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _interrupt)
    return run(DemoConfig(args.backend, args.out, args.rate, effect_args, goals))


if __name__ == '__main__':
    sys.exit(main())
