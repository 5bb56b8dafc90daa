"""valve_bench_loop: close the loop through the bench, over CAN, from recorded bags.

    valve_bench_loop [--mode bench|operation] [--effect coil_heating] [-o/--out DIR] [--quick]
                     [--plant-discharge-coefficient C_D]

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

The loop in service (``--mode operation``, :mod:`valve_bringup.operation_loop`) closes the
loop from the suite's own operation instead (docs/loop.md):

1. the suite runs as ``make demo`` does (:mod:`valve_bringup.demo`, CAN backend, lockstep
   clock, as fast as possible), the emulator's valve carrying the effect, the position
   controller moving the cylinder through a sequence of steps; the bag goes to
   ``DIR/before/``. The valve in service (emulated valve and plant orifice) discharges
   with its own C_d (``--plant-discharge-coefficient``, default 0.62), which the suite's
   set (0.8) does not know;
2. ``valve_identify --fit <bag>``: the bag's ``valve/state`` carries the interval-mean coil
   current and the duty commands, read as an operational record through the drive
   electronics (the last 30 % held out for validation);
3. ``valve_map --params`` rebuilds the static map from the identified parameters, whose
   flow scale (C_d C_A) is then calibrated on the before run's chamber mass balance
   (:func:`calibrate_flow_scale`: the current pins the stroke down only weakly, and a map
   that promises more opening than the valve gives slows the position loop);
   ``valve_simulator`` starts with that set (briefly), and the same position sequence runs
   again with ``flow_to_duty`` on it and the map (``DIR/after/``);
4. the position-tracking error (RMS of goal - position) and the flow prediction error (the
   model with nominal and with identified parameters, driven by the recorded duty commands,
   against the flow the chamber's mass balance measured) before and after go to
   ``DIR/loop.json`` and ``DIR/loop.md``.
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
from typing import TYPE_CHECKING

from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor

if TYPE_CHECKING:
    import numpy as np

    from valve_model_pkg.model import ValveParameters

__all__ = ['main', 'BenchRecord', 'record_bench_step', 'DEFAULT_EFFECT_PARAMS',
           'OPERATION_GOALS', 'run_operation_loop', 'tracking_error', 'flow_prediction_error']

#: Effect parameters of the emulated valve when --effect-param is not given. Coil heating
#: is made visible within the 0.8 s steps (a real coil's time constant is minutes).
DEFAULT_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    'coil_heating': ('thermal_resistance_k_per_w=5', 'thermal_time_constant_s=0.5'),
}

#: The effect of ``--mode operation`` when --effect is not given (one the identification
#: names from an operational record: docs/loop.md).
OPERATION_DEFAULT_EFFECT = 'eddy_current'

#: Effect parameters of the emulated valve in ``--mode operation`` (default: the
#: emulator's, half of the identification range of the switching field). Coil heating: a
#: small coil that heats within the run, with its time constant inside the
#: identification's range (1-1000 s). Through the chopper the current shows the heating
#: only in the boost and release phases, and a time constant of seconds is longer than the
#: identification's 0.4 s search window: the coil_heating refit scans amount and time
#: constant jointly on the fit window (identification.diagnosis.slow_effect); before that
#: the loop answered `none` or named it by chance (docs/loop.md, 2026-11-26).
OPERATION_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    'coil_heating': ('thermal_resistance_k_per_w=40', 'thermal_time_constant_s=3'),
}


#: Discharge coefficient of the physical valve in ``--mode operation`` (the emulated valve
#: and the plant's orifice). The suite's parameter set says 0.8 (an invented constant,
#: the issue's premise): a sharp-edged annular spool orifice discharges with about 0.6 to
#: 0.7, so the valve in service gives 0.775 x the flow the suite's datasheet set promises
#: and the before run's flow commands are on an uncalibrated scale, as in the field.
OPERATION_PLANT_DISCHARGE_COEFFICIENT = 0.62


@dataclass(frozen=True)
class BenchRecord:
    """One bench experiment: a voltage step of ``on_s`` after ``pre_s`` at rest."""

    name: str
    supply_voltage_v: float
    pre_s: float = 0.2
    on_s: float = 0.8
    post_s: float = 0.2


#: The listed candidate whose physics an emulator effect form (written independently of
#: the candidates, docs/effects.md) stands for: naming it, or `unlisted`, is a right answer.
NEAREST_CANDIDATE: dict[str, str] = {'saturation_tanh': 'magnetic_saturation',
                                     'eddy_ladder': 'eddy_current'}


def expected_answers(effect: str) -> list[str]:
    """The diagnoses that count as right for the effect the emulator's valve carries."""
    if not effect or effect == 'none':
        return ['none']
    if effect in NEAREST_CANDIDATE:
        return [NEAREST_CANDIDATE[effect], 'unlisted']
    return [effect]


#: Current ADC noise of the emulated bench controller [A] (standard deviation).
BENCH_ADC_NOISE_A = 2e-3


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

    # The emulator gets only its hardware (supply, pressure, effect); the bench mode (boost,
    # chopper and capacitor bypassed) is asked for over the bus, as of a real controller.
    # A real bench's current ADC has noise (2 mA here): a noise-free record would make
    # every residual smooth, and the identification counts few independent samples in a
    # smooth residual (its BIC then hardly tells an effect that halves the error).
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


def _identify(records: list[str], ident: Path, quick: bool, effect: str) -> dict:
    """Run ``valve_identify`` on ``records`` into ``ident``; say the diagnosis and errors.

    Returns the parsed ``report.json``.
    """
    _run(['valve_identify', *records, '--out', str(ident)] + (['--quick'] if quick else []))
    report = json.loads((ident / 'report.json').read_text())
    diag = report['diagnosis']
    _say(f'injected effect: {effect}; diagnosis: {diag["effect"]} '
         f'(confidence {diag.get("confidence", "?")})')
    for block_name in ('baseline', 'augmented'):
        for part in ('fit', 'validation'):
            m = report[block_name].get(part) or {}
            if m:
                _say(f'{block_name:>9} {part:>10}: IAE {m["iae"]:.4g} A s, RMSE '
                     f'{m["rmse"] * 1e3:.2f} mA, NRMSE {m["nrmse_pct"]:.2f} %')
    return report


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    _say('$ ' + ' '.join(argv))
    proc = subprocess.run(argv, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    for line in proc.stdout.splitlines()[-25:]:
        print(f'[{Path(argv[0]).name:>18}] {line}', flush=True)
    if proc.returncode != 0:
        raise RuntimeError(f'{argv[0]} failed with exit code {proc.returncode}')
    return proc


#: Position goals of the loop in service [m] and how long each is held [s] (simulated):
#: up and down strokes of different lengths, so the valve fills and exhausts.
OPERATION_GOALS = ((0.020, 2.0), (0.060, 2.0), (0.040, 2.0), (0.080, 2.0), (0.030, 2.0))
#: The same with --quick: three steps (a 4.5 s record after the 0.5 s pre-roll).
OPERATION_GOALS_QUICK = ((0.020, 1.5), (0.060, 1.5), (0.035, 1.5))


def _run_suite(label: str, run_dir: Path, effect_args: tuple[str, ...],
               goals: tuple[tuple[float, float], ...],
               flow_to_duty_args: tuple[str, ...] = (),
               plant_params: Path | None = None) -> Path:
    """One position-control run of the suite as ``make demo`` runs it; returns its bag.

    ``plant_params``: the physical valve's set (the emulated valve and the plant's orifice)
    where it differs from the suite's.
    """
    from valve_bringup.demo import DemoConfig, run
    cfg = DemoConfig(backend='can', out=run_dir, effect_args=effect_args, goals=goals,
                     clock='lockstep', real_time_factor_max=0.0,
                     flow_to_duty_args=flow_to_duty_args, plant_params_file=plant_params)
    _say(f'{label}: the suite on the CAN backend (lockstep, as fast as possible), '
         f'{len(goals)} position steps, output {run_dir}')
    code = run(cfg, out_given=True)
    if code == 130:
        raise KeyboardInterrupt('the suite run was interrupted')
    if code != 0:
        raise RuntimeError(f'the {label} run of the suite failed (exit code {code})')
    bags = sorted(p.parent for p in run_dir.glob('bag_*/metadata.yaml'))
    if len(bags) != 1:
        raise RuntimeError(f'{run_dir}: expected one bag, found {len(bags)}')
    return bags[0]


def goal_schedule(goals: tuple[tuple[float, float], ...]) -> list[tuple[float, float]]:
    """(goal [m], simulated time it takes effect [s]) of a demo run with these goals.

    The demo holds the simulation at each hold point (PRE_ROLL_S, then after each hold),
    sends the goal and lets the simulation go on only after the controller acknowledged it:
    every goal takes effect at its hold point, exactly, whatever the machine's load.
    """
    from valve_bringup.demo import PRE_ROLL_S
    out, t = [], PRE_ROLL_S
    for goal_m, hold_s in goals:
        out.append((float(goal_m), round(t, 3)))
        t += hold_s
    return out


def tracking_error(bag: Path, schedule: list[tuple[float, float]] | None = None) -> dict:
    """Position-tracking error of a run: goal in force - piston position, from the bag.

    With ``schedule`` (:func:`goal_schedule`: each goal and the simulated time it takes
    effect) the goals are placed on the joint states' simulation stamps by it: the same run
    gives the same number to the last digit. The bag's goals must be the schedule's, and
    the acknowledgement-based placement below must agree within one control tick, else
    ValueError (the bag is not the run the schedule describes).

    Each goal counts from the controller's acknowledgement: the change of
    ``cylinder/position_setpoint`` to it (the demo holds the simulation until then, so
    the goal takes effect there in every run). Both topics are std_msgs/Float64 without a
    header and are placed on the joint states' simulation time as the run report places the
    setpoints (the stamp of the last joint state received before each message); the goal
    message itself (the fallback when no setpoint acknowledges it) can land one joint-state
    tick early when the recorder receives it before that tick's joint state, which would
    count a step's full size for an extra 5 ms. The error is taken at every joint state
    from the first goal on.

    Returns
    -------
    dict
        ``rms_mm``, ``mean_abs_mm``, ``max_abs_mm`` [mm], ``duration_s`` [s], ``samples``.
    """
    import numpy as np

    from valve_model_pkg.cli.report import _sim_time_map  # the report's time base
    from valve_model_pkg.interface import (TOPIC_JOINT_STATES, TOPIC_POSITION_GOAL,
                                           TOPIC_POSITION_SETPOINT)
    from valve_model_pkg.recording import load_bag
    data = load_bag(bag, ['/' + TOPIC_JOINT_STATES, '/' + TOPIC_POSITION_GOAL,
                          '/' + TOPIC_POSITION_SETPOINT])
    joints = data.get('/' + TOPIC_JOINT_STATES)
    goals = data.get('/' + TOPIC_POSITION_GOAL)
    if joints is None or goals is None or not len(joints) or not len(goals):
        raise ValueError(f'{bag}: no {TOPIC_JOINT_STATES} or {TOPIC_POSITION_GOAL} messages')
    stamps = joints.stamp_ns if joints.stamp_ns is not None else joints.log_time_ns
    origin = int(stamps[0])
    tj = (np.asarray(stamps, dtype=np.int64) - origin) * 1e-9
    pos = np.array([p[0] for p in joints['position']], dtype=float)
    to_stamp = _sim_time_map(data, origin)

    def times(topic: object) -> np.ndarray:
        return to_stamp(topic) if to_stamp is not None else \
            (np.asarray(topic.log_time_ns, dtype=np.int64) - origin) * 1e-9
    tg = times(goals)
    goal = np.asarray(goals['data'], dtype=float)
    setp = data.get('/' + TOPIC_POSITION_SETPOINT)
    acknowledged = 0
    if setp is not None and len(setp):
        # the setpoint's changes, matched to the goals in order (the recorder may receive
        # the acknowledgement before the goal message itself)
        ts, sv = times(setp), np.asarray(setp['data'], dtype=float)
        changes = np.flatnonzero(np.diff(sv) != 0.0) + 1
        c = 0
        for i, value in enumerate(goal):
            while c < changes.size and sv[changes[c]] != value:
                c += 1
            if c == changes.size:
                break
            tg[i] = ts[changes[c]]
            acknowledged += 1
            c += 1
        tg = np.maximum.accumulate(tg)
    goals_from = 'controller acknowledgement' if acknowledged == goal.size \
        else f'{acknowledged} of {goal.size} goals acknowledged, others at the goal message'
    if schedule is not None:
        want = np.array([g for g, _ in schedule], dtype=float)
        if want.size != goal.size or not np.allclose(want, goal, rtol=0.0, atol=1e-9):
            raise ValueError(f'{bag}: goals {goal.tolist()} are not the schedule\'s '
                             f'{want.tolist()}')
        # the schedule in the bag's time base (seconds from the first joint state's stamp)
        t_sched = np.array([t for _, t in schedule], dtype=float) - origin * 1e-9
        tick = float(np.median(np.diff(tj))) if tj.size > 1 else 0.0
        off = np.abs(t_sched - tg)
        if np.any(off > 1.5 * tick):
            raise ValueError(f'{bag}: goals took effect at {tg.round(4).tolist()} s, not at '
                             f'the schedule\'s {t_sched.round(4).tolist()} s')
        tg = t_sched
        goals_from = ('demo schedule (each goal at its hold point, simulated time); the '
                      f'acknowledgements agree within {off.max() * 1e3:.1f} ms')
    k = np.searchsorted(tg, tj, side='right') - 1
    sel = k >= 0
    err = goal[k[sel]] - pos[sel]
    return {'rms_mm': float(np.sqrt(np.mean(err ** 2)) * 1e3),
            'mean_abs_mm': float(np.mean(np.abs(err)) * 1e3),
            'max_abs_mm': float(np.max(np.abs(err)) * 1e3),
            'duration_s': float(tj[sel][-1] - tj[sel][0]), 'samples': int(err.size),
            'goals_from': goals_from, 'bag': str(bag)}


#: Integration window of the chamber mass balance [s]: several 50 Hz PWM periods, so that
#: the static map's period-mean opening stands for the spool's motion within each window.
FLOW_CALIBRATION_WINDOW_S = 0.25


def _strictly_increasing(t: np.ndarray) -> np.ndarray:
    """Mask keeping the last of each run of equal stamps (a strictly ascending time base)."""
    import numpy as np
    return np.concatenate((np.diff(t) > 0.0, [True]))


def full_opening_area_m2(params: ValveParameters) -> float:
    """C_d C_A x_max [m^2]: the flow area at full opening that flow_to_duty relies on
    (the product C_d C_A alone absorbs an identified stroke's error)."""
    return params.discharge_coefficient * params.orifice_area_gradient_m * params.stroke_m


def _chamber_data(bag: Path) -> dict:
    """The chamber of a suite bag on the joint states' simulation stamps.

    ``t_s`` (absolute simulation time [s]), ``position_m``, ``pressure_pa`` (chamber,
    gauge, from ``valve/output_pressure``), ``duty`` (the command in force), the median
    ``pwm_frequency_hz`` and supply pressure ``supply_pa`` (gauge), the suite's
    ``cylinder`` (``CylinderParameters`` defaults, as the demo runs it: the bag does not
    carry them) and the ``state`` table (``valve/state``).

    Raises
    ------
    ValueError
        (``FlowIdentificationError``) the bag lacks a topic.
    """
    import numpy as np

    from valve_model_pkg.interface import (ATMOSPHERIC_PRESSURE_PA, TOPIC_DUTY_COMMAND,
                                           TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE,
                                           TOPIC_STATE)
    from valve_model_pkg.maps.flow_identification import FlowIdentificationError
    from valve_model_pkg.pneumatics.cylinder import CylinderParameters
    from valve_model_pkg.recording import load_bag
    topics = [TOPIC_JOINT_STATES, TOPIC_OUTPUT_PRESSURE, TOPIC_DUTY_COMMAND, TOPIC_STATE]
    data = load_bag(bag, ['/' + t for t in topics])
    missing = [t for t in topics if data.get('/' + t) is None or not len(data['/' + t])]
    if missing:
        raise FlowIdentificationError(f'{bag}: no {", ".join(missing)} messages')
    joints, pres, duty_cmd, state = (data['/' + t] for t in topics)
    # header stamps on simulation time (the CAN driver's valve/state stamps are not used:
    # they may repeat, docs/loop.md); the first stamps of a run can repeat too
    tj = np.asarray(joints.stamp_ns, dtype=np.int64) * 1e-9
    y = np.array([p[0] for p in joints['position']], dtype=float)
    # Messages stamped 0 come before the lockstep clock's first step, and only in some
    # runs (as discovery falls): kept, they shifted the mass balance's windows (which start
    # at the first stamp) by a step, and two loops on identical before runs calibrated C_A
    # differently in the 4th digit and tracked 8.97 vs 9.09 mm after (2026-11-26).
    keep = _strictly_increasing(tj) & (tj > 0.0)
    tj, y = tj[keep], y[keep]
    tp = np.asarray(pres.stamp_ns, dtype=np.int64) * 1e-9
    kp = _strictly_increasing(tp)
    p_gauge = np.interp(tj, tp[kp], np.asarray(pres['fluid_pressure'], float)[kp]) \
        - ATMOSPHERIC_PRESSURE_PA
    td = np.asarray(duty_cmd.stamp_ns, dtype=np.int64) * 1e-9
    k = np.clip(np.searchsorted(td, tj, side='right') - 1, 0, None)
    return {'t_s': tj, 'position_m': y, 'pressure_pa': p_gauge,
            'duty': np.asarray(duty_cmd['duty'], float)[k],
            'pwm_frequency_hz': float(np.median(np.asarray(duty_cmd['pwm_frequency'], float))),
            'supply_pa': float(np.median(np.asarray(state['supply_pressure'], float))),
            'cylinder': CylinderParameters(), 'state': state}


def calibrate_flow_scale(bag: Path, map_file: Path, params_file: Path, out_params: Path,
                         out_map: Path) -> dict:
    """Calibrate the flow scale of the identified set on the suite's own bag (issue item 3).

    The coil current sees the spool's stroke and spring pretension only weakly, so the
    identified ``stroke_m`` and ``spring_pretension_m`` (hence the map's absolute opening
    x_avg(d)) can be off by tens of percent while the current fits well; ``flow_to_duty``
    would then command a flow scale that the valve does not deliver. The chamber's mass
    balance (C2) measures the flow the valve delivers: with the opening the identified map
    gives at the recorded duty commands, ``identify_from_chamber`` fits C_d C_A (C_d kept,
    C_A scaled), so the product C_d C_A x_map(d) -- what ``flow_to_duty`` inverts -- matches
    the valve. The map's curves are unchanged (they do not depend on C_d, C_A).

    The bag does not carry the cylinder: its geometry, bleed and polytropic exponent are the
    suite's cylinder as the demo runs it (``CylinderParameters`` defaults).

    Parameters
    ----------
    bag : pathlib.Path
        A bag of the suite (``cylinder/joint_states``, ``valve/output_pressure``,
        ``valve/duty_command``, ``valve/state``).
    map_file, params_file : pathlib.Path
        The map rebuilt from the identified parameters, and those parameters.
    out_params, out_map : pathlib.Path
        Where the calibrated parameter set and map go (``out_map`` may be ``map_file``).

    Returns
    -------
    dict
        ``product_m`` (C_d C_A [m]), ``prior_product_m``, ``ratio``, ``interval_m``,
        ``discharge_coefficient``, ``orifice_area_gradient_m``, ``window_s``, the mass
        balance error before/after [% of the largest windowed valve flow], the files.

    Raises
    ------
    ValueError
        (``FlowIdentificationError``) the bag lacks a topic, or the valve never opens.
    """
    import numpy as np

    from valve_model_pkg.maps import load_map
    from valve_model_pkg.maps.flow_check import map_flow_position
    from valve_model_pkg.maps.flow_identification import (
        ChamberRecord, chamber_volume_m3, identify_from_chamber, recalibrated_map,
        write_parameters)
    from valve_model_pkg.model import load_parameters
    ch = _chamber_data(bag)
    tj, y, p_gauge, duty, freq, p_sup, cyl = (ch[k] for k in (
        't_s', 'position_m', 'pressure_pa', 'duty', 'pwm_frequency_hz', 'supply_pa',
        'cylinder'))
    params = load_parameters(str(params_file))
    dmap = load_map(map_file)
    grid = np.linspace(0.0, 1.0, 401)
    x_grid = params.stroke_m * np.array([map_flow_position(dmap, float(g), freq, p_sup)
                                         for g in grid])
    rec = ChamberRecord(tj - tj[0], p_gauge,
                        chamber_volume_m3(y, cyl.bore_diameter_m, cyl.dead_volume_m3),
                        np.interp(duty, grid, x_grid), np.full_like(tj, p_sup))
    res = identify_from_chamber(rec, params, polytropic_exponent=cyl.polytropic_exponent,
                                bleed_discharge_area_m2=cyl.bleed_discharge_area_m2,
                                window_s=FLOW_CALIBRATION_WINDOW_S)
    est = res.estimate
    write_parameters(res.params, out_params, header=(
        f'The identified set ({params_file}) with the flow scale calibrated on the chamber '
        f'mass balance of {bag}\n(valve_bench_loop --mode operation): C_d C_A = '
        f'{est.product_m:.6g} m (was {est.prior_product_m:.6g} m), C_d kept, C_A scaled.'))
    recalibrated_map(dmap, res.params, f'the chamber of {bag.name}').save(out_map)
    return {'source': 'chamber mass balance of the before run (eq. C2), opening from the '
                      'identified map at the recorded duty commands',
            'product_m': est.product_m, 'prior_product_m': est.prior_product_m,
            'ratio': est.product_m / est.prior_product_m,
            'interval_m': list(est.interval_m),
            'discharge_coefficient': res.params.discharge_coefficient,
            'orifice_area_gradient_m': res.params.orifice_area_gradient_m,
            'full_opening_area_m2': full_opening_area_m2(res.params),
            'window_s': res.window_s, 'windows': int(est.n_points),
            'balance_error_pct': {'before': res.error_before_pct,
                                  'after': res.error_after_pct},
            'cylinder': {'bore_diameter_m': cyl.bore_diameter_m,
                         'dead_volume_m3': cyl.dead_volume_m3,
                         'bleed_discharge_area_m2': cyl.bleed_discharge_area_m2,
                         'polytropic_exponent': cyl.polytropic_exponent},
            'params': str(out_params), 'map': str(out_map)}


#: Windows of the flow prediction error [s]: five 50 Hz PWM periods, short against a step.
FLOW_PREDICTION_WINDOW_S = 0.1


def flow_prediction_error(bag: Path, params_files: dict[str, Path | None]) -> dict:
    """Mass-flow prediction error of parameter sets against the flow the chamber received.

    Measured: the valve's flow into the chamber, window by window, from the chamber's mass
    balance (C2, C3: pressure, piston position, the suite's cylinder; ``chamber_valve_flow``)
    -- the valve/state ``mass_flow`` is not a measurement (the CAN driver derives it from
    the spool position with the suite's own orifice constants). Predicted: the model with
    each set, driven by the recorded duty commands (``InputTrace.pwm_commands`` on the
    period grid the identification's reader reconstructs) at the record's median pressures
    for the spool's flow force; eq. (12) of its spool position with the set's C_d C_A at
    the supply and chamber pressures of each instant, averaged over the same windows.

    Parameters
    ----------
    bag : pathlib.Path
        A bag of the suite (``valve/state`` through the drive electronics, the chamber).
    params_files : dict
        Label -> parameter YAML (None = the packaged nominal set).

    Returns
    -------
    dict
        Per label ``rms_kg_s`` [kg/s], ``rms_pct`` [% of full flow] and the mean flows;
        ``full_flow_kg_s`` (eq. 12 of the nominal set, spool open, at the median supply
        pressure into the atmosphere), ``windows``, ``window_s``, ``measured_by``.
    """
    import numpy as np

    from valve_model_pkg.identification.bag_reader import read_bag
    from valve_model_pkg.maps.flow_identification import (ChamberRecord, chamber_valve_flow,
                                                          chamber_volume_m3)
    from valve_model_pkg.model import (InputTrace, load_parameters, orifice_mass_flow,
                                       simulate_trace_batch)
    m = read_bag(bag)
    d = m.drive
    if d is None:
        raise ValueError(f'{bag}: valve/state is not an operational record (no duty commands)')
    ch = _chamber_data(bag)
    state = ch['state']
    if len(state) != m.t_s.size:
        raise ValueError(f'{bag}: {len(state)} valve/state messages but {m.t_s.size} samples')
    p_sup = np.asarray(state['supply_pressure'], dtype=float)
    p_out = np.asarray(state['output_pressure'], dtype=float)
    nominal = load_parameters()
    cyl = ch['cylinder']
    tj = ch['t_s']
    starts_w, measured = chamber_valve_flow(
        ChamberRecord(tj, ch['pressure_pa'],
                      chamber_volume_m3(ch['position_m'], cyl.bore_diameter_m,
                                        cyl.dead_volume_m3),
                      np.zeros_like(tj), np.full_like(tj, ch['supply_pa'])),
        nominal, bleed_discharge_area_m2=cyl.bleed_discharge_area_m2,
        polytropic_exponent=cyl.polytropic_exponent, window_s=FLOW_PREDICTION_WINDOW_S)
    trace = InputTrace.pwm_commands(d.t_s, d.duty, d.pwm_frequency_hz, d.supply_voltage_v)
    # a 0.1 ms grid resolves the stroke (under 1 ms)
    t_fine = np.arange(1, int(np.ceil(m.t_s[-1] / 1e-4)) + 1) * 1e-4
    labels = list(params_files)
    params = [load_parameters(str(p)) if p is not None else nominal
              for p in params_files.values()]
    res = simulate_trace_batch(params, trace, t_fine, sampling='instant',
                               supply_pressure_pa=float(np.median(p_sup)),
                               output_pressure_pa=float(np.median(p_out)))
    # the record's times on the joint states' clock: valve/state stamps are simulation time
    # too (they can repeat by a step, docs/loop.md: a 1 ms shift in 0.1 s windows)
    t0 = int(state.stamp_ns[0]) * 1e-9 - float(m.t_s[0])
    t_abs = t_fine + t0
    ps_f = np.interp(t_fine, m.t_s, p_sup)
    po_f = np.interp(t_fine, m.t_s, p_out)
    # windows the chamber and the simulation both cover whole
    ends_w = starts_w + FLOW_PREDICTION_WINDOW_S
    use = (starts_w >= t_abs[0]) & (ends_w <= t_abs[-1]) & (ends_w <= tj[-1])
    if np.count_nonzero(use) < 3:
        raise ValueError(f'{bag}: fewer than 3 flow windows of '
                         f'{FLOW_PREDICTION_WINDOW_S:g} s covered by both the chamber and '
                         'valve/state')
    idx = np.floor((t_abs - starts_w[0]) / FLOW_PREDICTION_WINDOW_S).astype(int)
    inside = (idx >= 0) & (idx < starts_w.size)
    full = float(orifice_mass_flow(nominal.stroke_m, float(np.median(p_sup)), 0.0, nominal))
    out: dict = {'full_flow_kg_s': full, 'samples': int(m.t_s.size),
                 'duration_s': float(m.t_s[-1] - m.t_s[0]), 'bag': str(bag),
                 'windows': int(np.count_nonzero(use)), 'window_s': FLOW_PREDICTION_WINDOW_S,
                 'measured_by': 'chamber mass balance (C2, C3) of the suite\'s cylinder'}
    for n, (label, par) in enumerate(zip(labels, params)):
        flow = orifice_mass_flow(np.clip(res.spool_position_m[n], 0.0, None), ps_f, po_f, par)
        sums = np.bincount(idx[inside], flow[inside], starts_w.size)
        counts = np.bincount(idx[inside], minlength=starts_w.size)
        with np.errstate(invalid='ignore', divide='ignore'):
            predicted = sums / counts
        err = (predicted - measured)[use]
        rms = float(np.sqrt(np.mean(err ** 2)))
        out[label] = {'rms_kg_s': rms, 'rms_pct': 100.0 * rms / full,
                      'mean_predicted_kg_s': float(np.mean(predicted[use])),
                      'mean_measured_kg_s': float(np.mean(measured[use]))}
    return out


def _simulator_check(params: Path) -> bool:
    """Start ``valve_simulator`` with ``params`` for a few seconds; True if it simulated."""
    sim = subprocess.Popen(['valve_simulator', '--ros-args', '-p',
                            f'params_file:={params.resolve()}'],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           start_new_session=True)
    try:
        time.sleep(4.0)
    finally:
        os.killpg(sim.pid, signal.SIGINT)
        try:
            sim_out, _ = sim.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(sim.pid, signal.SIGKILL)
            sim_out, _ = sim.communicate()
    started = 'simulating' in sim_out
    _say(f'valve_simulator with the identified parameters: '
         f'{"started and stopped cleanly" if started else "FAILED"}')
    if not started:
        print(sim_out, flush=True)
    return started


def _figures(block: dict) -> dict:
    return {part: {k: block[part][k] for k in ('iae', 'rmse', 'nrmse_pct')
                   if k in block[part]}
            for part in ('fit', 'validation') if block.get(part)}


def write_plant_parameters(out_file: Path, discharge_coefficient: float) -> dict:
    """The physical valve of the loop in service: the suite's set with its own C_d.

    Returns the ``plant`` block of loop.json (what the valve in service is, so the loop's
    flow calibration can be checked against it).

    Raises
    ------
    ValueError
        A discharge coefficient outside (0, 1] (``ParameterError``).
    """
    from valve_model_pkg.maps.flow_identification import write_parameters
    from valve_model_pkg.model import load_parameters
    suite = load_parameters()
    plant = suite.replace(discharge_coefficient=float(discharge_coefficient))
    write_parameters(plant, out_file, header=(
        'The physical valve of valve_bench_loop --mode operation: the suite\'s parameter set '
        f'with C_d = {plant.discharge_coefficient:g}\n(the suite says '
        f'{suite.discharge_coefficient:g}); the emulated valve and the plant\'s orifice carry '
        'it, the suite does not know it.'))
    return {'params': str(out_file), 'discharge_coefficient': plant.discharge_coefficient,
            'orifice_area_gradient_m': plant.orifice_area_gradient_m,
            'stroke_m': plant.stroke_m,
            'full_opening_area_m2': full_opening_area_m2(plant),
            'suite_discharge_coefficient': suite.discharge_coefficient,
            'suite_full_opening_area_m2': full_opening_area_m2(suite)}


def run_operation_loop(out: Path, effect: str, effect_args: tuple[str, ...],
                       quick: bool = False,
                       plant_discharge_coefficient: float =
                       OPERATION_PLANT_DISCHARGE_COEFFICIENT) -> int:
    """The loop in service (``--mode operation``); returns the exit code.

    The valve in service (emulated valve and plant orifice) discharges with
    ``plant_discharge_coefficient`` where the suite's set says 0.8: the before run commands
    flow on an uncalibrated scale, which the loop's flow calibration recovers.
    """
    goals = OPERATION_GOALS_QUICK if quick else OPERATION_GOALS
    stages: dict[str, float] = {}
    t_start = time.monotonic()

    def stage(name: str, t0: float) -> None:
        stages[name] = round(time.monotonic() - t0, 2)
        _say(f'stage {name}: {stages[name]:.1f} s')

    for sub in ('before', 'after'):
        if (out / sub / 'report').exists():
            raise ValueError(f'{out / sub} already holds a run; give another --out')
    plant_file = (out / 'plant_valve.yaml').resolve()
    plant = write_plant_parameters(plant_file, plant_discharge_coefficient)
    _say(f'the valve in service: C_d {plant["discharge_coefficient"]:g} (the suite\'s set '
         f'says {plant["suite_discharge_coefficient"]:g}), {plant_file}')
    t0 = time.monotonic()
    bag_before = _run_suite('before', out / 'before', effect_args, goals,
                            plant_params=plant_file)
    stage('run_before', t0)

    t0 = time.monotonic()
    ident = out / 'identification'
    report = _identify(['--fit', str(bag_before)], ident, quick, effect)
    stage('identification', t0)
    diag = report['diagnosis']
    base, aug = report['baseline'], report['augmented']
    params = (ident / 'params.yaml').resolve()

    t0 = time.monotonic()
    map_file = (out / 'map_identified.json').resolve()
    # flow_to_duty sends 50 Hz (its pwm_frequency_hz) and inverts the map at the supply
    # pressure, interpolating between the map's pressures: 50 Hz over 0..6 bar suffices.
    _run(['valve_map', '--params', str(params), '-o', str(map_file), '--frequencies', '50',
          '--pressures-bar', '0', '2', '4', '6', '--fig-dir', str(out / 'map'), '-q'])
    stage('map', t0)

    t0 = time.monotonic()
    # The flow scale of the identified set, calibrated on the before run's chamber (the
    # current sees the stroke and the spring pretension only weakly: docs/loop.md); the map
    # keeps its curves and gets the calibrated C_A, so flow_to_duty restarts with both.
    params_loop = (out / 'params_identified.yaml').resolve()
    try:
        flow_cal = calibrate_flow_scale(bag_before, map_file, params, params_loop, map_file)
        # Compared with the valve in service on the flow area at full opening (the product
        # C_d C_A absorbs the identified stroke's error: the current sees the stroke weakly).
        flow_cal['full_opening_error_pct'] = 100.0 * (
            flow_cal['full_opening_area_m2'] / plant['full_opening_area_m2'] - 1.0)
        flow_cal['suite_full_opening_error_pct'] = 100.0 * (
            plant['suite_full_opening_area_m2'] / plant['full_opening_area_m2'] - 1.0)
        _say(f'flow scale calibrated on the chamber of the before run: C_d C_A '
             f'{flow_cal["prior_product_m"] * 1e3:.4g} -> {flow_cal["product_m"] * 1e3:.4g} '
             f'mm (x {flow_cal["ratio"]:.3f}), mass balance error '
             f'{flow_cal["balance_error_pct"]["before"]:.1f} -> '
             f'{flow_cal["balance_error_pct"]["after"]:.1f} %; flow area at full opening '
             f'{flow_cal["full_opening_error_pct"]:+.1f} % off the valve in service (the '
             f'suite\'s set: {flow_cal["suite_full_opening_error_pct"]:+.1f} %)')
    except ValueError as err:  # FlowIdentificationError: the identified set as it is
        _say(f'flow scale not calibrated ({err}): flow_to_duty gets the identified set')
        flow_cal = {'error': str(err)}
        params_loop = params
    stage('flow_calibration', t0)
    t0 = time.monotonic()
    sim_ok = _simulator_check(params_loop)
    stage('simulator_check', t0)
    if not sim_ok:
        return 1

    t0 = time.monotonic()
    bag_after = _run_suite('after', out / 'after', effect_args, goals, flow_to_duty_args=(
        '-p', f'map_file:={map_file}', '-p', f'params_file:={params_loop}'),
        plant_params=plant_file)
    stage('run_after', t0)

    t0 = time.monotonic()
    schedule = goal_schedule(goals)
    tracking = {'before': tracking_error(bag_before, schedule),
                'after': tracking_error(bag_after, schedule)}
    sets: dict[str, Path | None] = {'nominal': None, 'identified': params}
    if params_loop != params:
        sets['calibrated'] = params_loop
    flow_runs = {name: flow_prediction_error(bag, sets)
                 for name, bag in (('before_run', bag_before), ('after_run', bag_after))}
    stage('evaluation', t0)
    # The headline flow error is on the after run (a record the identification never saw),
    # with the set the loop hands on (the identified one, flow scale calibrated).
    in_force = 'calibrated' if 'calibrated' in sets else 'identified'
    flow = {'before': {'params': 'nominal', **flow_runs['after_run']['nominal']},
            'after': {'params': in_force, **flow_runs['after_run'][in_force]},
            'record': 'after_run', 'full_flow_kg_s': flow_runs['after_run']['full_flow_kg_s'],
            'runs': flow_runs}
    stages['total'] = round(time.monotonic() - t_start, 2)
    loop = {
        'mode': 'operation', 'effect_injected': effect, 'emulator_args': list(effect_args),
        'goals': [{'position_mm': g * 1e3, 'hold_s': h} for g, h in goals],
        'quick': quick,
        'diagnosis': diag,
        'judgement': {'expected': expected_answers(effect),
                      'right': diag.get('effect') in expected_answers(effect)},
        'baseline': _figures(base), 'augmented': _figures(aug),
        'identification': {'report': str(ident / 'report.md'), 'params': str(params),
                           'timings_s': report.get('timings_s', {})},
        'map': str(map_file), 'params_in_force': str(params_loop),
        'plant': plant, 'flow_calibration': flow_cal, 'simulator_started': sim_ok,
        'tracking': tracking, 'flow': flow, 'stages_s': stages,
        'units': {'iae': 'A s', 'rmse': 'A', 'rms_mm': 'mm', 'rms_kg_s': 'kg/s',
                  'rms_pct': '% of full flow', 'stages_s': 's (wall time)'},
    }
    (out / 'loop.json').write_text(json.dumps(loop, indent=2, default=str) + '\n')
    (out / 'loop.md').write_text(_loop_markdown(loop, out))
    _say(f'tracking error (RMS goal - position): before {tracking["before"]["rms_mm"]:.3f} mm, '
         f'after {tracking["after"]["rms_mm"]:.3f} mm')
    _say(f'flow prediction error (RMS, % of full flow, after run): nominal '
         f'{flow["before"]["rms_pct"]:.2f} %, identified {flow["after"]["rms_pct"]:.2f} %')
    _say('stage times [s]: ' + ', '.join(f'{k} {v:.1f}' for k, v in stages.items()))
    _say(f'loop report: {out / "loop.md"} (and loop.json)')
    return 0


def _loop_markdown(loop: dict, out: Path) -> str:
    """``loop.md``: the loop's numbers for a person, with pointers to the plots."""
    diag, base, aug = loop['diagnosis'], loop['baseline'], loop['augmented']
    tr, fl, st = loop['tracking'], loop['flow'], loop['stages_s']

    def fig(block: dict, part: str, key: str, scale: float = 1.0, fmt: str = '.4g') -> str:
        v = (block.get(part) or {}).get(key)
        return 'n/a' if v is None else format(v * scale, fmt)
    cal = loop.get('flow_calibration') or {}
    cal_note = ' (flow scale calibrated)' if 'product_m' in cal else ''
    lines = [
        '# The loop in service', '',
        f'Effect carried by the emulator\'s valve: **{loop["effect_injected"]}**; named by '
        f'the identification: **{diag.get("effect")}** (confidence '
        f'{diag.get("confidence", "n/a")}).', '']
    plant = loop.get('plant') or {}
    if plant:
        lines += [
            f'The valve in service discharges with C_d {plant["discharge_coefficient"]:g} '
            f'(the suite\'s set says {plant["suite_discharge_coefficient"]:g}): its flow area '
            f'at full opening is {plant["full_opening_area_m2"] * 1e6:.4g} mm^2, the suite '
            f'assumes {plant["suite_full_opening_area_m2"] * 1e6:.4g} mm^2. The suite does '
            f'not know it (`plant_valve.yaml`).', '']
    lines += [
        '## Coil current (identification from the before run\'s bag)', '',
        '| model | fit IAE [A s] | validation IAE [A s] | validation RMSE [mA] |',
        '|---|---|---|---|',
        f'| baseline (nominal equations) | {fig(base, "fit", "iae")} | '
        f'{fig(base, "validation", "iae")} | {fig(base, "validation", "rmse", 1e3, ".2f")} |',
        f'| augmented ({diag.get("effect")}) | {fig(aug, "fit", "iae")} | '
        f'{fig(aug, "validation", "iae")} | {fig(aug, "validation", "rmse", 1e3, ".2f")} |',
        '', 'Validation: the last 30 % of the record, never seen by the fit. Details and plots: '
        '[identification/report.md](identification/report.md).', '',
        '## Position tracking (RMS of goal - position over the run)', '',
        '| run | flow_to_duty with | RMS [mm] | mean abs [mm] | max abs [mm] |',
        '|---|---|---|---|---|',
        f'| before | nominal parameters and map | {tr["before"]["rms_mm"]:.3f} | '
        f'{tr["before"]["mean_abs_mm"]:.3f} | {tr["before"]["max_abs_mm"]:.2f} |',
        f'| after | identified parameters and map{cal_note} | {tr["after"]["rms_mm"]:.3f} | '
        f'{tr["after"]["mean_abs_mm"]:.3f} | {tr["after"]["max_abs_mm"]:.2f} |',
        '', 'Each goal counts from its hold point (the demo holds the simulation until the '
        'controller acknowledged it); the RMS includes the step transients.', '']
    if 'product_m' in cal:
        lines += [
            f'Flow scale of the identified set, calibrated on the before run\'s chamber mass '
            f'balance (opening from the identified map at the recorded duties): C_d C_A '
            f'{cal["prior_product_m"] * 1e3:.4g} -> {cal["product_m"] * 1e3:.4g} mm '
            f'(x {cal["ratio"]:.3f}; balance error {cal["balance_error_pct"]["before"]:.1f} '
            f'-> {cal["balance_error_pct"]["after"]:.1f} %). flow_to_duty ran with '
            '`params_identified.yaml` and `map_identified.json`.'
            + (f' Flow area at full opening (C_d C_A x stroke of that set) '
               f'{cal["full_opening_area_m2"] * 1e6:.4g} mm^2: '
               f'{cal["full_opening_error_pct"]:+.1f} % off the valve in service (the '
               f'suite\'s set: {cal["suite_full_opening_error_pct"]:+.1f} %).'
               if 'full_opening_error_pct' in cal else ''), '']
    elif cal:
        lines += [f'Flow scale not calibrated: {cal.get("error")}', '']
    lines += [
        'Plots: [before/report/report.md](before/report/report.md) '
        '(before/report/overview.png), [after/report/report.md](after/report/report.md) '
        '(after/report/overview.png).', '',
        '## Flow prediction (model driven by the recorded duty commands vs the flow the '
        'chamber received)', '',
        f'RMS error over {FLOW_PREDICTION_WINDOW_S:g} s windows in % of full flow '
        f'({fl["full_flow_kg_s"] * 1e3:.2f} g/s: spool open, supply into the atmosphere). '
        'Measured by the chamber\'s mass balance (C2, C3: pressure, piston position, the '
        'suite\'s cylinder); valve/state mass_flow is not a measurement (the CAN driver '
        'derives it with the suite\'s orifice constants).', '',
        '| record | nominal parameters | identified parameters | identified, flow scale '
        'calibrated |', '|---|---|---|---|']
    for name, run in fl['runs'].items():
        calibrated = run.get('calibrated', {}).get('rms_pct')
        lines.append(f'| {name.replace("_", " ")} | {run["nominal"]["rms_pct"]:.2f} % | '
                     f'{run["identified"]["rms_pct"]:.2f} % | '
                     f'{"n/a" if calibrated is None else format(calibrated, ".2f") + " %"} |')
    lines += ['', 'The after run was not used by the identification. The static map from the '
              'identified parameters: `map_identified.json` (figures in `map/`).', '',
              '## Time of each stage (wall time)', '',
              '| stage | s |', '|---|---|']
    lines += [f'| {k} | {v:.1f} |' for k, v in st.items()]
    timings = loop['identification'].get('timings_s') or {}
    if timings:
        lines += ['', 'Identification split: ' + ', '.join(
            f'{k} {v:.1f} s' for k, v in timings.items() if isinstance(v, (int, float)))]
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``valve_bench_loop``."""
    parser = argparse.ArgumentParser(prog='valve_bench_loop',
                                     description=__doc__.split('\n')[0])
    parser.add_argument('--mode', choices=('bench', 'operation'), default='bench',
                        help='bench: bare-coil voltage steps (default); operation: the loop '
                        'in service, from position-control runs of the suite (docs/loop.md)')
    parser.add_argument('--effect', default=None,
                        help='physical effect of the emulated valve (default coil_heating in '
                        'bench mode, eddy_current in operation mode)')
    parser.add_argument('--effect-param', action='append', default=None, metavar='FIELD=VALUE',
                        help='value of an effect parameter, passed to the emulator (default '
                        'for coil_heating: a small coil that heats noticeably within a '
                        'second, R_th 5 K/W, tau 0.5 s)')
    parser.add_argument('-o', '--out', type=Path, default=Path('bench_loop_output'),
                        help='directory for the bags, the identification and the map')
    parser.add_argument('--plant-discharge-coefficient', type=float,
                        default=OPERATION_PLANT_DISCHARGE_COEFFICIENT, metavar='C_D',
                        help='(operation) discharge coefficient of the valve in service, '
                        'which the suite does not know (default '
                        f'{OPERATION_PLANT_DISCHARGE_COEFFICIENT:g}; the suite\'s set says '
                        '0.8, and 0.8 here runs the loop on a valve with the suite\'s flow '
                        'scale)')
    parser.add_argument('--quick', action='store_true',
                        help='quick identification settings (fewer starts)')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    def _interrupt(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(signal.Signals(signum).name)
    signal.signal(signal.SIGTERM, _interrupt)

    out = args.out
    c_d = args.plant_discharge_coefficient
    if not (c_d == c_d and 0.0 < c_d <= 1.0):   # c_d == c_d: not NaN
        parser.error(f'--plant-discharge-coefficient {c_d!r}: expected a number in (0, 1]')
    if args.effect is None:
        args.effect = 'coil_heating' if args.mode == 'bench' else OPERATION_DEFAULT_EFFECT
    from valve_model_pkg.model import EFFECTS
    from valve_model_pkg.model.parameters import EMULATOR_EFFECTS  # forms, not candidates
    if args.effect != 'none' and args.effect not in EFFECTS and args.effect not in \
            EMULATOR_EFFECTS:
        parser.error(f'--effect {args.effect!r}: expected none or one of {", ".join(EFFECTS)} '
                     f'or an emulator form {", ".join(EMULATOR_EFFECTS)}')
    out.mkdir(parents=True, exist_ok=True)
    effect_args: tuple[str, ...] = ()
    effect_params = args.effect_param
    if effect_params is None:
        defaults = DEFAULT_EFFECT_PARAMS if args.mode == 'bench' \
            else OPERATION_EFFECT_PARAMS
        effect_params = list(defaults.get(args.effect, ()))
    if args.effect and args.effect != 'none':
        effect_args = ('--effect', args.effect) + tuple(
            a for item in effect_params for a in ('--effect-param', item))
    if args.mode == 'operation':
        try:
            return run_operation_loop(out, args.effect, effect_args, quick=args.quick,
                                      plant_discharge_coefficient=c_d)
        except KeyboardInterrupt:
            _say('interrupted')
            return 130
        except (ChildExited, RuntimeError, OSError, KeyError, ValueError) as err:
            _say(f'error: {err}')
            return 1
    stamp = time.strftime('%Y%m%d-%H%M%S')
    try:
        fit = record_bench_step(BenchRecord('fit', 24.0), out / f'bench_24V_{stamp}',
                                effect_args)
        val = record_bench_step(BenchRecord('validate', 15.0), out / f'bench_15V_{stamp}',
                                effect_args)
        ident = out / 'identification'
        _identify(['--fit', str(fit), '--validate', str(val)], ident, args.quick, args.effect)
        params = ident / 'params.yaml'
        _run(['valve_simulate', '--experiment', 'step', '--voltage', '24', '--duration',
              '0.02', '--params', str(params), '--out', str(out / 'step24_identified.csv')])
        _run(['valve_map', '--params', str(params), '-o', str(out / 'map_identified.json'),
              '--frequencies', '50', '--pressures-bar', '0', '4', '--duty-step', '0.02',
              '--fig-dir', str(out)])
        if not _simulator_check(params):
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
