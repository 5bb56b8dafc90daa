"""valve_bench_loop: close the loop through the bench, over CAN, from recorded bags.

    valve_bench_loop [--effect coil_heating] [-o/--out DIR] [--quick]

1. Bench experiments on the CAN backend: the controller emulator runs a valve that carries
   a physical effect the nominal model lacks (``--effect``); the driver publishes
   ``valve/state`` and ``valve_recorder`` records it. As on a real identification bench,
   the controller's drive electronics are bypassed (bare coil, no chopper, no capacitor)
   and the coil sees a voltage step: 24 V for the fit record, 15 V for the validation
   record (the paper's Figs. 4 and 5), each a few seconds long so that slow effects show.
   The PWM edges fall on the telemetry grid (the controller applies commands at period
   starts), so the 1 kHz state stream carries the coil voltage exactly.
2. ``valve_identify --fit <24 V bag> --validate <15 V bag>`` identifies the parameters,
   studies the residual, names the missing effect and reports the error before and after.
3. The updated parameters drive the model again: ``valve_simulate --params`` and
   ``valve_map --params`` with the identified set, and ``valve_simulator`` starts with it.

Why not identify from the demo's position-control run: with the drive electronics on,
the coil voltage is a 20 kHz chopper signal that a 1 kHz state stream cannot carry, so
the current cannot be simulated from the recorded voltage. The bench records use the
same backend, driver, topics and recorder as the demo.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor

__all__ = ['main', 'BenchRecord', 'record_bench_step', 'DEFAULT_EFFECT_PARAMS']

#: Effect parameters of the emulated valve when --effect-param is not given. Coil heating
#: is made visible within the 0.8 s steps (a real coil's time constant is minutes).
DEFAULT_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    'coil_heating': ('thermal_resistance_k_per_w=5', 'thermal_time_constant_s=0.5'),
}


@dataclass(frozen=True)
class BenchRecord:
    """One bench experiment: a voltage step of ``on_s`` after ``pre_s`` at rest."""

    name: str
    supply_voltage_v: float
    pre_s: float = 0.2
    on_s: float = 0.8
    post_s: float = 0.2


def _say(text: str) -> None:
    print(f'[{"bench_loop":>18}] {text}', flush=True)


def record_bench_step(record: BenchRecord, bag: Path, effect_args: tuple[str, ...],
                      supply_pressure_pa: float = 4.0e5) -> Path:
    """Run one bench step through emulator + CAN driver and record it to ``bag``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from valve_bringup.backend import can_backend_processes
    from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_STATE
    from valve_model_pkg.nodes.probe import StateProbe

    emulator_args = ('--no-current-control', '--no-capacitor',
                     '--supply-voltage-v', f'{record.supply_voltage_v:g}',
                     '--supply-pressure-pa', f'{supply_pressure_pa:g}', *effect_args)
    specs = can_backend_processes(rate_hz=1000.0, emulator_args=emulator_args) + [
        ProcessSpec('valve_recorder', ['valve_recorder', TOPIC_STATE, TOPIC_DUTY_COMMAND,
                                       '-o', str(bag)])]
    with Supervisor() as sup:
        for spec in specs:
            sup.start(spec)
        rclpy.init()
        probe = StateProbe('bench_loop')
        executor = SingleThreadedExecutor()
        executor.add_node(probe)
        duty = {'value': 0.0}
        # Republished at 20 Hz: the driver's watchdog closes the valve without commands.
        probe.create_timer(0.05, lambda: probe.command(duty['value'], 50.0))

        def spin(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.02)
                sup.check_alive()
        try:
            deadline = time.monotonic() + 60.0
            while probe.count < 100:
                spin(0.1)
                if time.monotonic() > deadline:
                    raise ChildExited('no valve/state from the CAN driver within 60 s')
            spin(1.5)  # the recorder subscribes
            _say(f'{record.name}: {record.supply_voltage_v:g} V step for {record.on_s:g} s')
            spin(record.pre_s)
            duty['value'] = 1.0
            probe.reset_window()
            spin(record.on_s)
            w = probe.window()
            duty['value'] = 0.0
            spin(record.post_s)
            _say(f'{record.name}: mean current {w.current_mean_a:.3f} A while on, '
                 f'{probe.count} states seen, gaps {probe.gaps}')
        finally:
            executor.shutdown()
            probe.destroy_node()
            rclpy.try_shutdown()
        sup.stop()
    return bag


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    _say('$ ' + ' '.join(argv))
    proc = subprocess.run(argv, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    for line in proc.stdout.splitlines()[-25:]:
        print(f'[{Path(argv[0]).name:>18}] {line}', flush=True)
    if proc.returncode != 0:
        raise RuntimeError(f'{argv[0]} failed with exit code {proc.returncode}')
    return proc


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_bench_loop``."""
    parser = argparse.ArgumentParser(prog='valve_bench_loop',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('--effect', default='coil_heating',
                        help='physical effect of the emulated valve (default coil_heating)')
    parser.add_argument('--effect-param', action='append', default=None, metavar='FIELD=VALUE',
                        help='value of an effect parameter, passed to the emulator (default '
                        'for coil_heating: a small coil that heats noticeably within a '
                        'second, R_th 5 K/W, tau 0.5 s)')
    parser.add_argument('-o', '--out', type=Path, default=Path('bench_loop_output'),
                        help='directory for the bags, the identification and the map')
    parser.add_argument('--quick', action='store_true',
                        help='quick identification settings (fewer starts)')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _interrupt)

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    effect_args: tuple[str, ...] = ()
    effect_params = args.effect_param
    if effect_params is None:
        effect_params = list(DEFAULT_EFFECT_PARAMS.get(args.effect, ()))
    if args.effect and args.effect != 'none':
        effect_args = ('--effect', args.effect) + tuple(
            a for item in effect_params for a in ('--effect-param', item))
    stamp = time.strftime('%Y%m%d-%H%M%S')
    try:
        fit = record_bench_step(BenchRecord('fit', 24.0), out / f'bench_24V_{stamp}',
                                effect_args)
        val = record_bench_step(BenchRecord('validate', 15.0), out / f'bench_15V_{stamp}',
                                effect_args)
        ident = out / 'identification'
        _run(['valve_identify', '--fit', str(fit), '--validate', str(val), '--out', str(ident)]
             + (['--quick'] if args.quick else []))
        report = json.loads((ident / 'report.json').read_text())
        diag = report['diagnosis']
        base, aug = report['baseline'], report['augmented']
        _say(f'injected effect: {args.effect}; diagnosis: {diag["effect"]} '
             f'(confidence {diag.get("confidence", "?")})')
        for block_name, block in (('baseline', base), ('augmented', aug)):
            for part in ('fit', 'validation'):
                m = block.get(part) or {}
                if m:
                    _say(f'{block_name:>9} {part:>10}: IAE {m["iae"]:.4g} A s, RMSE '
                         f'{m["rmse"] * 1e3:.2f} mA, NRMSE {m["nrmse_pct"]:.2f} %')
        params = ident / 'params.yaml'
        _run(['valve_simulate', '--experiment', 'step', '--voltage', '24', '--duration',
              '0.02', '--params', str(params), '--out', str(out / 'step24_identified.csv')])
        _run(['valve_map', '--params', str(params), '-o', str(out / 'map_identified.json'),
              '--frequencies', '50', '--pressures-bar', '0', '4', '--duty-step', '0.02',
              '--fig-dir', str(out)])
        sim = subprocess.Popen(['valve_simulator', '--ros-args', '-p',
                                f'params_file:={params.resolve()}'],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               start_new_session=True)
        time.sleep(4.0)
        os.killpg(sim.pid, signal.SIGINT)
        sim_out, _ = sim.communicate(timeout=20)
        started = 'simulating' in sim_out
        _say(f'valve_simulator with the identified parameters: '
             f'{"started and stopped cleanly" if started else "FAILED"}')
        if not started:
            print(sim_out)
            return 1
        _say(f'identification report: {ident / "report.md"}')
        return 0
    except KeyboardInterrupt:
        _say('interrupted')
        return 130
    except (ChildExited, RuntimeError, OSError, KeyError, ValueError) as err:
        _say(f'error: {err}')
        return 1


if __name__ == '__main__':
    sys.exit(main())
