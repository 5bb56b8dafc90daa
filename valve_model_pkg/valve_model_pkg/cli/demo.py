"""valve_demo: run the suite as separate processes, drive it, and stop everything cleanly.

This is what ``make demo`` runs. It starts the nodes with :mod:`valve_model_pkg.supervisor`
(the ``launch`` package is not in the ROS 2 wheels; users with a full ROS install have the
launch files in ``launch/``), shows what is running, drives the valve through a sequence
of duty commands from its own rclpy node, prints what it observes, and stops all processes
on Ctrl-C or when the sequence ends.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from valve_model_pkg.supervisor import ChildExited, ProcessSpec, Supervisor

__all__ = ['main', 'backend_processes']


@dataclass(frozen=True)
class DutyStep:
    """One step of the demo sequence: hold a duty at a PWM frequency for a while."""

    duty: float
    pwm_frequency_hz: float
    hold_s: float


SEQUENCE = (
    DutyStep(0.0, 50.0, 1.0),
    DutyStep(0.25, 50.0, 1.5),
    DutyStep(0.5, 50.0, 1.5),
    DutyStep(0.75, 50.0, 1.5),
    DutyStep(0.5, 100.0, 1.5),
    DutyStep(0.0, 50.0, 1.0),
)


def backend_processes(backend: str, *, rate_hz: float = 1000.0,
                      extra_sim_args: tuple[str, ...] = ()) -> list[ProcessSpec]:
    """The processes that provide ``valve/state`` for a backend (``sim`` or ``can``)."""
    if backend == 'sim':
        return [ProcessSpec('valve_simulator', [
            'valve_simulator', '--ros-args', '-p', f'publish_rate_hz:={rate_hz}',
            *extra_sim_args])]
    if backend == 'can':
        from valve_driver_pkg.backend import can_backend_processes  # only when asked for
        return can_backend_processes(rate_hz=rate_hz)
    raise ValueError(f'unknown backend {backend!r}: expected "sim" or "can"')


def _drive(sup: Supervisor, steps: tuple[DutyStep, ...]) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from valve_model_pkg.nodes.probe import StateProbe

    rclpy.init()
    probe = StateProbe('valve_demo')
    executor = SingleThreadedExecutor()
    executor.add_node(probe)
    try:
        sup.say('waiting for valve/state ...')
        deadline = time.monotonic() + 30.0
        while probe.count == 0:
            executor.spin_once(timeout_sec=0.1)
            sup.check_alive()
            if time.monotonic() > deadline:
                sup.say('no valve/state within 30 s: giving up')
                return 1
        sup.say('valve/state is arriving. What is running:\n' + sup.table())
        sup.say(f'{"duty":>6} {"f_pwm":>7} {"rate":>8} {"x_avg/x_max":>11} '
                f'{"i_mean":>8} {"i_max":>7} {"flow":>10}')
        for step in steps:
            probe.command(step.duty, step.pwm_frequency_hz)
            probe.reset_window()
            end = time.monotonic() + step.hold_s
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
                sup.check_alive()
            w = probe.window()
            sup.say(f'{step.duty:6.2f} {step.pwm_frequency_hz:5.0f}Hz {w.rate_hz:6.0f}Hz '
                    f'{w.position_avg_pct:10.1f}% {w.current_mean_a:7.3f}A '
                    f'{w.current_max_a:6.3f}A {w.mass_flow_kg_s * 1e3:7.3f}g/s')
        sup.say(f'{probe.count} state messages received, sequence gaps: {probe.gaps}')
        return 0
    finally:
        executor.shutdown()
        probe.destroy_node()
        rclpy.try_shutdown()


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_demo``."""
    parser = argparse.ArgumentParser(prog='valve_demo', description=__doc__.split('\n')[0])
    parser.add_argument('--backend', choices=('sim', 'can'), default='sim',
                        help='valve/state from the simulator or the CAN driver + emulator')
    parser.add_argument('--rate', type=float, default=1000.0, help='valve/state rate [Hz]')
    parser.add_argument('--out', type=Path, default=Path('demo_output'),
                        help='directory for the demo\'s files')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    # Ctrl-C / SIGTERM: raise in the main thread so the supervisor's context exit stops all.
    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _interrupt)

    with Supervisor() as sup:
        sup.say(f'valve suite demo, backend {args.backend}, ROS_DOMAIN_ID='
                f'{os.environ.get("ROS_DOMAIN_ID", "0")}, discovery '
                f'{os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]}')
        try:
            for spec in backend_processes(args.backend, rate_hz=args.rate):
                sup.start(spec)
            code = _drive(sup, SEQUENCE)
        except KeyboardInterrupt:
            sup.say('interrupted: stopping all processes')
            code = 130
        except ChildExited as err:
            sup.say(f'error: {err}')
            code = 1
        sup.say('stopping ...')
        codes = sup.stop()
        sup.say('stopped: ' + ', '.join(f'{n} exit {c}' for n, c in codes.items()))
    return code


if __name__ == '__main__':
    sys.exit(main())
