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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from valve_msgs.msg import ValveState

from valve_bringup.backend import can_backend_processes
from valve_bringup.loop_commands import identify, run_command, say, simulator_starts
from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification.bag_reader import read_bag
from valve_model_pkg.identification.measurement import current_response
from valve_model_pkg.interface import TOPIC_DUTY_COMMAND, TOPIC_STATE
from valve_model_pkg.model import load_parameters
from valve_model_pkg.nodes.probe import StateProbe

__all__ = ['BenchRecord', 'BenchStep', 'BENCH_RECORDS', 'BENCH_ADC_NOISE_A',
           'DEFAULT_EFFECT_PARAMS', 'bag_gaps', 'check_bench_bag', 'record_bench_step',
           'record_checked_step', 'run_bench_loop']

#: Effect parameters of the emulated valve when --effect-param is not given. Coil heating
#: is made visible within the 0.8 s steps (a real coil's time constant is minutes) with a
#: time constant inside the identification's search range (EFFECTS' bounds, 1-1000 s):
#: a truth outside it can only be fitted at the bound, and the augmented error then
#: depends on how long the step happens to last.
DEFAULT_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    'coil_heating': ('thermal_resistance_k_per_w=12', 'thermal_time_constant_s=2'),
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
#: Longest wait for the valve state to show a commanded change [s] (wall time: under load
#: the state stream can lag the commands by a second).
_ACK_TIMEOUT_S = 20.0
#: A state shows the step on while its coil voltage is at least this share of the supply
#: (bench mode: the bare coil sees the supply, unchopped, for as long as duty = 1).
_ON_SHARE = 0.5
#: Share of the step's duration a recorded bag must hold with the voltage on.
_MIN_ON_SHARE = 0.9
#: Time the recorder is given after the last state of a step before it is stopped [s].
_RECORDER_CATCHES_UP_S = 0.5


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


@dataclass(frozen=True)
class BenchStep:
    """What :func:`record_bench_step` recorded.

    Attributes
    ----------
    bag : pathlib.Path
        The bag.
    problem : str or None
        Why the bag is no record of the step (None: the state stream showed the whole
        step); :func:`check_bench_bag` then judges the bag itself.
    on_latency_s, off_latency_s : float
        Wall time from the command (duty 1, duty 0) to the first state that shows it [s]:
        the lateness of the command and state path, reported, never fatal.
    mean_current_a : float
        Mean coil current over the states that showed the step on [A].
    states_on : int
        States seen with the step on.
    """

    bag: Path
    problem: str | None
    on_latency_s: float
    off_latency_s: float
    mean_current_a: float
    states_on: int


def _spin(executor: SingleThreadedExecutor, sup: Supervisor, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)
        sup.check_alive()


def _stamp_s(msg: ValveState) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def _wait_for(executor: SingleThreadedExecutor, sup: Supervisor, probe: StateProbe,
              done: Callable[[ValveState], bool], timeout_s: float = _ACK_TIMEOUT_S
              ) -> ValveState | None:
    """Spin until the last state the probe received satisfies ``done``; None on timeout."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        _spin(executor, sup, 0.02)
        last = probe.window().last
        if last is not None and done(last):
            return last
    return None


def _step_is_on(record: BenchRecord) -> Callable[[ValveState], bool]:
    """A state that shows the step on: duty 1 in force at the controller and the coil at
    the supply voltage (the bench mode is in force, the command arrived)."""
    return lambda m: (m.duty >= 1.0
                      and m.coil_voltage >= _ON_SHARE * record.supply_voltage_v)


def _run_step(executor: SingleThreadedExecutor, sup: Supervisor, probe: StateProbe,
              duty: dict, record: BenchRecord, bag: Path) -> BenchStep:
    """Command the step and time it by the valve state: ``on_s`` of states showing it on
    (by their stamps), then ``post_s`` of states showing it off; commands keep flowing."""
    is_on = _step_is_on(record)
    _wait_for(executor, sup, probe, lambda m: m.duty == 0.0 and not is_on(m))
    _spin(executor, sup, record.pre_s)
    duty['value'] = 1.0
    t_cmd = time.monotonic()
    probe.reset_window()
    first_on = _wait_for(executor, sup, probe, is_on)
    on_latency = time.monotonic() - t_cmd
    if first_on is None:
        duty['value'] = 0.0
        return BenchStep(bag, f'the valve state did not show the step within '
                         f'{_ACK_TIMEOUT_S:g} s of the command', on_latency, 0.0, 0.0, 0)
    probe.reset_window()
    t_on = _stamp_s(first_on)
    lost = _wait_for(executor, sup, probe,
                     lambda m: not is_on(m) or _stamp_s(m) - t_on >= record.on_s,
                     record.on_s + _ACK_TIMEOUT_S)
    w = probe.window()
    duty['value'] = 0.0
    t_cmd = time.monotonic()
    problem = None
    if lost is None or not is_on(lost):
        problem = ('the step went off before its end (at '
                   f'{_stamp_s(lost) - t_on:.3f} s)' if lost is not None
                   else 'the state stream stopped during the step')
    first_off = _wait_for(executor, sup, probe, lambda m: m.duty == 0.0)
    off_latency = time.monotonic() - t_cmd
    if first_off is not None:
        t_off = _stamp_s(first_off)
        _wait_for(executor, sup, probe, lambda m: _stamp_s(m) - t_off >= record.post_s)
    _spin(executor, sup, _RECORDER_CATCHES_UP_S)
    return BenchStep(bag, problem, on_latency, off_latency, w.current_mean_a, w.count)


def record_bench_step(record: BenchRecord, bag: Path, effect_args: tuple[str, ...],
                      supply_pressure_pa: float = 4.0e5) -> BenchStep:
    """Run one bench step through emulator + CAN driver and record it to ``bag``.

    The emulator gets only its hardware (supply, pressure, ADC noise, effect); the bench
    mode (boost, chopper and capacitor bypassed) is asked for over the bus, as of a real
    controller. The step is timed by the valve state, not by the clock of the commands:
    it starts when a state shows duty 1 at the supply voltage (command and bench mode in
    force), lasts ``on_s`` by the states' stamps, and the duty command keeps being sent
    throughout. How late the state showed each command is said (under load the state
    stream lags by up to a second).
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
            step = _run_step(executor, sup, probe, duty, record, bag)
            say(f'{record.name}: mean current {step.mean_current_a:.3f} A over '
                f'{step.states_on} states on; the state showed the step '
                f'{1e3 * step.on_latency_s:.0f} ms and its end {1e3 * step.off_latency_s:.0f} '
                f'ms after the command; {probe.count} states seen, gaps {probe.gaps}')
        finally:
            executor.shutdown()
            probe.destroy_node()
            rclpy.try_shutdown()
        sup.stop()
    return step


def check_bench_bag(record: BenchRecord, bag: Path) -> str | None:
    """Why the recorded ``bag`` is no record of the step (None: it is one).

    The bag must hold the step with the voltage on for at least
    :data:`_MIN_ON_SHARE` of ``on_s`` and states at rest after it, and its current must
    respond to the voltage (:func:`~valve_model_pkg.identification.measurement.
    current_response`, at the packaged parameter set's coil resistance).
    """
    try:
        m = read_bag(bag)
    except MeasurementFormatError as err:
        return str(err)
    on = np.flatnonzero(m.voltage_v >= _ON_SHARE * record.supply_voltage_v)
    if on.size == 0:
        return 'the bag holds no state with the step on'
    held = float(m.t_s[on[-1]] - m.t_s[on[0]])
    if held < _MIN_ON_SHARE * record.on_s:
        return f'the bag holds {held:.3f} s of the {record.on_s:g} s step'
    if on[-1] == m.n_samples - 1:
        return 'the bag ends before the step does'
    r = current_response(m, load_parameters().coil_resistance_ohm)
    if r is not None and not r.responds:
        return (f'the current does not respond to the {r.voltage_on_v:.3g} V step: '
                f'{1e3 * r.response_a:.3g} mA, not more than {1e3 * r.threshold_a:.3g} mA')
    return None


def bag_gaps(bag: Path) -> str:
    """Where the states of ``bag`` are further apart than 1.5 of their median spacing, in
    words: the instants the controller skipped or the bus lost (the states are stamped when
    their frame was on the bus, so a skip is a gap, not a bunch)."""
    t = read_bag(bag).t_s
    dt = np.diff(t)
    if dt.size == 0:
        return 'no state spacing'
    step = float(np.median(dt))
    gaps = dt[dt > 1.5 * step]
    if gaps.size == 0:
        return f'{t.size} states {1e3 * step:.3g} ms apart, no gap'
    return (f'{t.size} states {1e3 * step:.3g} ms apart, {gaps.size} gaps (largest '
            f'{1e3 * gaps.max():.3g} ms, {1e3 * (gaps.sum() - gaps.size * step):.3g} ms '
            'of states missing in all)')


def record_checked_step(record: BenchRecord, out: Path, stamp: str,
                        effect_args: tuple[str, ...],
                        record_step: Callable[..., BenchStep] = record_bench_step) -> Path:
    """Record ``record`` into ``out`` and check its bag; once more if the step is not in it.

    Parameters
    ----------
    record : BenchRecord
    out : pathlib.Path
        Directory of the bags (``bench_<V>V_<stamp>``, ``..._again`` for the second).
    stamp : str
        Names the bags.
    effect_args : tuple of str
        The emulator's effect arguments.
    record_step : callable
        Records one step: ``record_step(record, bag, effect_args) -> BenchStep``.

    Returns
    -------
    pathlib.Path
        The bag that holds the step (:func:`check_bench_bag`).

    Raises
    ------
    RuntimeError
        The second recording is no record of the step either (one line naming it).
    """
    stem = f'bench_{record.supply_voltage_v:g}V_{stamp}'
    for attempt, bag in enumerate((out / stem, out / f'{stem}_again')):
        step = record_step(record, bag, effect_args)
        problem = step.problem or check_bench_bag(record, bag)
        if problem is None:
            say(f'{record.name}: {bag.name}: {bag_gaps(bag)}')
            return bag
        if attempt == 0:
            say(f'{record.name}: {bag.name} is no record of the step ({problem}); '
                'recording it once more')
    raise RuntimeError(f'bench step {record.name} ({record.supply_voltage_v:g} V) not '
                       f'recorded twice: {bag.name}: {problem}')


def run_bench_loop(out: Path, effect: str, effect_args: tuple[str, ...],
                   quick: bool = False) -> int:
    """Record the bench steps, identify, simulate and map with the identified set.

    Returns 0, or 1 when ``valve_simulator`` does not start with the identified set.

    Raises
    ------
    RuntimeError
        A step not recorded in two attempts (:func:`check_bench_bag`), or a command that
        fails.
    """
    stamp = time.strftime('%Y%m%d-%H%M%S')
    fit, val = (record_checked_step(r, out, stamp, effect_args) for r in BENCH_RECORDS)
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
