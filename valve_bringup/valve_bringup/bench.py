"""The loop through the bench (``valve_bench_loop --mode bench``): voltage steps on a bare
coil over CAN, recorded, identified, and the identified set driving the model again.

As on a real identification bench, the controller's drive electronics are bypassed (bare
coil, no chopper, no capacitor) and the coil sees a voltage step: 24 V for the fit record,
15 V for the validation record (the paper's Figs. 4 and 5), each a few seconds long so that
slow effects show. The PWM edges fall on the telemetry grid (the controller applies
commands at period starts), so the 1 kHz state stream carries the coil voltage exactly.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor

from valve_bringup.backend import can_backend_processes
from valve_bringup.loop_commands import identify, run_command, say, simulator_starts
from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor
from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_STATE
from valve_model_pkg.nodes.probe import StateProbe

__all__ = ['BenchRecord', 'BENCH_RECORDS', 'BENCH_ADC_NOISE_A', 'DEFAULT_EFFECT_PARAMS',
           'record_bench_step', 'run_bench_loop']

#: Effect parameters of the emulated valve when --effect-param is not given. Coil heating
#: is made visible within the 0.8 s steps (a real coil's time constant is minutes).
DEFAULT_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    'coil_heating': ('thermal_resistance_k_per_w=5', 'thermal_time_constant_s=0.5'),
}

#: Current ADC noise of the emulated bench controller [A] (standard deviation). A real
#: bench's ADC has noise: a noise-free record makes every residual smooth, and the
#: identification counts few independent samples in a smooth residual (its information
#: criterion then hardly tells an effect that halves the error).
BENCH_ADC_NOISE_A = 2e-3

#: States the driver must have published before a step [1], and how long it may take [s].
_STATES_BEFORE_STEP = 100
_DRIVER_UP_TIMEOUT_S = 60.0
#: Time for the recorder to subscribe before a step [s].
_RECORDER_SUBSCRIBES_S = 1.5
#: Period of the duty command (the driver's watchdog closes the valve without commands).
_COMMAND_PERIOD_S = 0.05


@dataclass(frozen=True)
class BenchRecord:
    """One bench experiment: a voltage step of ``on_s`` after ``pre_s`` at rest [s]."""

    name: str
    supply_voltage_v: float
    pre_s: float = 0.2
    on_s: float = 0.8
    post_s: float = 0.2


#: The fit record (24 V) and the validation record (15 V).
BENCH_RECORDS = (BenchRecord('fit', 24.0), BenchRecord('validate', 15.0))


def _spin(executor: SingleThreadedExecutor, sup: Supervisor, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)
        sup.check_alive()


def record_bench_step(record: BenchRecord, bag: Path, effect_args: tuple[str, ...],
                      supply_pressure_pa: float = 4.0e5) -> Path:
    """Run one bench step through emulator + CAN driver and record it to ``bag``.

    The emulator gets only its hardware (supply, pressure, ADC noise, effect); the bench
    mode (boost, chopper and capacitor bypassed) is asked for over the bus, as of a real
    controller.
    """
    emulator_args = ('--supply-voltage-v', f'{record.supply_voltage_v:g}',
                     '--supply-pressure-pa', f'{supply_pressure_pa:g}',
                     '--current-noise-a', f'{BENCH_ADC_NOISE_A:g}', *effect_args)
    specs = can_backend_processes(rate_hz=1000.0, emulator_args=emulator_args,
                                  drive_mode='bench') + [
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
        probe.create_timer(_COMMAND_PERIOD_S, lambda: probe.command(duty['value'], 50.0))
        try:
            deadline = time.monotonic() + _DRIVER_UP_TIMEOUT_S
            while probe.count < _STATES_BEFORE_STEP:
                _spin(executor, sup, 0.1)
                if time.monotonic() > deadline:
                    raise ChildExited(f'no valve/state from the CAN driver within '
                                      f'{_DRIVER_UP_TIMEOUT_S:g} s')
            _spin(executor, sup, _RECORDER_SUBSCRIBES_S)
            say(f'{record.name}: {record.supply_voltage_v:g} V step for {record.on_s:g} s')
            _spin(executor, sup, record.pre_s)
            duty['value'] = 1.0
            probe.reset_window()
            _spin(executor, sup, record.on_s)
            w = probe.window()
            duty['value'] = 0.0
            _spin(executor, sup, record.post_s)
            say(f'{record.name}: mean current {w.current_mean_a:.3f} A while on, '
                f'{probe.count} states seen, gaps {probe.gaps}')
        finally:
            executor.shutdown()
            probe.destroy_node()
            rclpy.try_shutdown()
        sup.stop()
    return bag


def run_bench_loop(out: Path, effect: str, effect_args: tuple[str, ...],
                   quick: bool = False) -> int:
    """Record the bench steps, identify, simulate and map with the identified set.

    Returns 0, or 1 when ``valve_simulator`` does not start with the identified set.
    """
    stamp = time.strftime('%Y%m%d-%H%M%S')
    fit, val = (record_bench_step(r, out / f'bench_{r.supply_voltage_v:g}V_{stamp}',
                                  effect_args) for r in BENCH_RECORDS)
    ident = out / 'identification'
    identify(['--fit', str(fit), '--validate', str(val)], ident, quick, effect)
    params = ident / 'params.yaml'
    run_command(['valve_simulate', '--experiment', 'step', '--voltage', '24', '--duration',
                 '0.02', '--params', str(params), '--out',
                 str(out / 'step24_identified.csv')])
    run_command(['valve_map', '--params', str(params), '-o', str(out / 'map_identified.json'),
                 '--frequencies', '50', '--pressures-bar', '0', '4', '--duty-step', '0.02',
                 '--fig-dir', str(out)])
    if not simulator_starts(params):
        return 1
    say(f'identification report: {ident / "report.md"}')
    return 0
