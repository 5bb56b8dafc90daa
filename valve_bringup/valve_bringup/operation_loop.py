"""The loop in service (``valve_bench_loop --mode operation``, docs/loop.md): identify
from the suite's own operation, calibrate, and run again.

0. The valve in service (emulated valve and plant orifice) discharges with its own C_d
   (``plant_discharge_coefficient``, default 0.62), which the suite's set (0.8) does not
   know (:func:`write_plant_parameters`).
1. The suite runs as ``make demo`` does (:mod:`valve_bringup.demo`, CAN backend, lockstep
   clock, as fast as possible), the emulator's valve carrying the effect, the position
   controller moving the cylinder through
   :data:`~valve_model_pkg.pneumatics.goals.OPERATION_GOALS`; the bag goes to
   ``DIR/before/``.
2. ``valve_identify --fit <bag>``: the bag's ``valve/state`` carries the interval-mean coil
   current and the duty commands, read as an operational record through the drive
   electronics (the last 30 % held out for validation).
3. ``valve_map --params`` rebuilds the static map from the identified parameters, whose
   flow scale (C_d C_A) is then calibrated on the before run's chamber mass balance
   (:func:`valve_model_pkg.analysis.calibrate_flow_scale`); ``valve_simulator`` starts
   with that set (briefly), and the same position sequence runs again with
   ``flow_to_duty`` on it and the map (``DIR/after/``).
4. The position-tracking error and the flow prediction error before and after
   (:mod:`valve_model_pkg.analysis`) go to ``DIR/loop.json`` and ``DIR/loop.md``.
"""
from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from valve_bringup.demo import DemoConfig, run
from valve_bringup.loop_commands import (error_figures, identify, run_command, say,
                                         simulator_starts)
from valve_bringup.loop_report import loop_markdown
from valve_model_pkg.analysis import (calibrate_flow_scale, flow_prediction_error,
                                      full_opening_area_m2, map_opening_m, run_chamber,
                                      run_tracking_error)
from valve_model_pkg.maps import load_map
from valve_model_pkg.maps.flow_identification import recalibrated_map, write_parameters
from valve_model_pkg.model import load_parameters
from valve_model_pkg.pneumatics.goals import (OPERATION_GOALS, OPERATION_QUICK_GOALS,
                                              GoalSequence, goal_schedule)

__all__ = ['run_operation_loop', 'OPERATION_DEFAULT_EFFECT', 'OPERATION_EFFECT_PARAMS',
           'OPERATION_PLANT_DISCHARGE_COEFFICIENT', 'NEAREST_CANDIDATE', 'expected_answers',
           'PlantValve', 'write_plant_parameters']

#: The effect of ``--mode operation`` when --effect is not given (one the identification
#: names from an operational record: docs/loop.md).
OPERATION_DEFAULT_EFFECT = 'eddy_current'

#: Effect parameters of the emulated valve in ``--mode operation`` (default: the
#: emulator's, half of the identification range of the switching field). Coil heating: a
#: small coil that heats within the run, with its time constant inside the
#: identification's range (1-1000 s). Through the chopper the current shows the heating
#: only in the boost and release phases, and a time constant of seconds is longer than the
#: identification's search window: its refit scans amount and time constant jointly on
#: the fit window (identification.diagnosis).
OPERATION_EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    'coil_heating': ('thermal_resistance_k_per_w=40', 'thermal_time_constant_s=3'),
}

#: Discharge coefficient of the physical valve in ``--mode operation`` (the emulated valve
#: and the plant's orifice). The suite's parameter set says 0.8, an invented constant: a
#: sharp-edged annular spool orifice discharges with about 0.6 to 0.7, so the valve in
#: service gives 0.775 x the flow the suite's datasheet set promises and the before run's
#: flow commands are on an uncalibrated scale, as in the field.
OPERATION_PLANT_DISCHARGE_COEFFICIENT = 0.62

#: The listed candidate whose physics an emulator effect form (written independently of
#: the candidates, docs/effects.md) stands for: naming it, or `unlisted`, is a right answer.
NEAREST_CANDIDATE: dict[str, str] = {'saturation_tanh': 'magnetic_saturation',
                                     'eddy_ladder': 'eddy_current'}

#: The static map the after run's flow_to_duty inverts: its PWM frequency (50 Hz) over the
#: supply pressures it interpolates between [bar].
_MAP_FREQUENCIES_HZ = ('50',)
_MAP_PRESSURES_BAR = ('0', '2', '4', '6')


def expected_answers(effect: str) -> list[str]:
    """The diagnoses that count as right for the effect the emulator's valve carries."""
    if not effect or effect == 'none':
        return ['none']
    if effect in NEAREST_CANDIDATE:
        return [NEAREST_CANDIDATE[effect], 'unlisted']
    return [effect]


@dataclass(frozen=True)
class PlantValve:
    """The valve in service: the suite's set with its own discharge coefficient.

    Attributes
    ----------
    params_file : pathlib.Path
    discharge_coefficient, orifice_area_gradient_m, stroke_m : float
        C_d [1], C_A [m], x_max [m] of the valve in service.
    full_opening_area_m2 : float
        Its C_d C_A x_max [m^2].
    suite_discharge_coefficient, suite_full_opening_area_m2 : float
        The same of the suite's set.
    """

    params_file: Path
    discharge_coefficient: float
    orifice_area_gradient_m: float
    stroke_m: float
    full_opening_area_m2: float
    suite_discharge_coefficient: float
    suite_full_opening_area_m2: float

    def to_json(self) -> dict:
        """``loop.json`` ``plant``."""
        return {'params': str(self.params_file),
                'discharge_coefficient': self.discharge_coefficient,
                'orifice_area_gradient_m': self.orifice_area_gradient_m,
                'stroke_m': self.stroke_m, 'full_opening_area_m2': self.full_opening_area_m2,
                'suite_discharge_coefficient': self.suite_discharge_coefficient,
                'suite_full_opening_area_m2': self.suite_full_opening_area_m2}


def write_plant_parameters(out_file: Path, discharge_coefficient: float) -> PlantValve:
    """Write the valve in service's parameter set: the suite's with its own C_d.

    Raises
    ------
    ValueError
        A discharge coefficient outside (0, 1] (``ParameterError``).
    """
    suite = load_parameters()
    plant = suite.replace(discharge_coefficient=float(discharge_coefficient))
    write_parameters(plant, out_file, header=(
        'The physical valve of valve_bench_loop --mode operation: the suite\'s parameter set '
        f'with C_d = {plant.discharge_coefficient:g}\n(the suite says '
        f'{suite.discharge_coefficient:g}); the emulated valve and the plant\'s orifice carry '
        'it, the suite does not know it.'))
    return PlantValve(out_file, plant.discharge_coefficient, plant.orifice_area_gradient_m,
                      plant.stroke_m, full_opening_area_m2(plant), suite.discharge_coefficient,
                      full_opening_area_m2(suite))


class _Stages:
    """Wall time of each stage of the loop [s], said as each ends."""

    def __init__(self) -> None:
        self.times_s: dict[str, float] = {}
        self._start = time.monotonic()

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        t0 = time.monotonic()
        yield
        self.times_s[name] = round(time.monotonic() - t0, 2)
        say(f'stage {name}: {self.times_s[name]:.1f} s')

    def total(self) -> dict[str, float]:
        """The stage times with ``total``."""
        self.times_s['total'] = round(time.monotonic() - self._start, 2)
        return self.times_s


def _run_suite(label: str, run_dir: Path, effect_args: tuple[str, ...], goals: GoalSequence,
               flow_to_duty_args: tuple[str, ...] = (),
               plant_params: Path | None = None) -> Path:
    """One position-control run of the suite as ``make demo`` runs it; returns its bag.

    ``plant_params``: the physical valve's set (the emulated valve and the plant's orifice)
    where it differs from the suite's.
    """
    cfg = DemoConfig(backend='can', out=run_dir, effect_args=effect_args, goals=goals,
                     clock='lockstep', real_time_factor_max=0.0,
                     flow_to_duty_args=flow_to_duty_args, plant_params_file=plant_params)
    say(f'{label}: the suite on the CAN backend (lockstep, as fast as possible), '
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


def _build_map(params: Path, out: Path) -> Path:
    """``valve_map`` of the identified set: the map the after run's flow_to_duty inverts."""
    map_file = (out / 'map_identified.json').resolve()
    run_command(['valve_map', '--params', str(params), '-o', str(map_file), '--frequencies',
                 *_MAP_FREQUENCIES_HZ, '--pressures-bar', *_MAP_PRESSURES_BAR,
                 '--fig-dir', str(out / 'map'), '-q'])
    return map_file


@dataclass(frozen=True)
class _Calibrated:
    """The set flow_to_duty gets in the after run, and ``loop.json`` ``flow_calibration``."""

    params_file: Path
    report: dict


def _calibrate(bag: Path, map_file: Path, params_file: Path, out_params: Path,
               plant: PlantValve) -> _Calibrated:
    """Calibrate the identified set's flow scale on the before run's chamber; write the
    calibrated set to ``out_params`` and give the map its C_d, C_A. A bag that cannot
    calibrate leaves the identified set as it is."""
    try:
        chamber = run_chamber(bag)
        identified = load_parameters(str(params_file))
        duty_map = load_map(map_file)
        cal = calibrate_flow_scale(chamber, map_opening_m(
            duty_map, identified, chamber.duty, chamber.pwm_frequency_hz,
            chamber.supply_pressure_pa), identified)
    except ValueError as err:  # FlowIdentificationError, RunAnalysisError
        say(f'flow scale not calibrated ({err}): flow_to_duty gets the identified set')
        return _Calibrated(params_file, {'error': str(err)})
    write_parameters(cal.params, out_params, header=(
        f'The identified set ({params_file}) with the flow scale calibrated on the chamber '
        f'mass balance of {bag}\n(valve_bench_loop --mode operation): C_d C_A = '
        f'{cal.product_m:.6g} m (was {cal.prior_product_m:.6g} m), C_d kept, C_A scaled.'))
    recalibrated_map(duty_map, cal.params, f'the chamber of {bag.name}').save(map_file)
    report = {**cal.to_json(), 'params': str(out_params), 'map': str(map_file),
              # against the valve in service, on the flow area at full opening (the
              # product C_d C_A absorbs the identified stroke's error)
              'full_opening_error_pct': 100.0 * (
                  full_opening_area_m2(cal.params) / plant.full_opening_area_m2 - 1.0),
              'suite_full_opening_error_pct': 100.0 * (
                  plant.suite_full_opening_area_m2 / plant.full_opening_area_m2 - 1.0)}
    say(f'flow scale calibrated on the chamber of the before run: C_d C_A '
        f'{cal.prior_product_m * 1e3:.4g} -> {cal.product_m * 1e3:.4g} mm (x {cal.ratio:.3f}), '
        f'mass balance error {cal.balance_error_before_pct:.1f} -> '
        f'{cal.balance_error_after_pct:.1f} %; flow area at full opening '
        f'{report["full_opening_error_pct"]:+.1f} % off the valve in service (the suite\'s '
        f'set: {report["suite_full_opening_error_pct"]:+.1f} %)')
    return _Calibrated(out_params, report)


@dataclass(frozen=True)
class _Evaluation:
    """``loop.json`` ``tracking`` and ``flow``."""

    tracking: dict
    flow: dict


def _evaluate(bags: dict[str, Path], goals: GoalSequence, params_file: Path,
              params_in_force: Path) -> _Evaluation:
    """Tracking error of both runs on the goal schedule; flow prediction error of the
    nominal, identified and (if calibrated) calibrated sets on both runs.

    The headline flow error is on the after run (a record the identification never saw),
    nominal set against the set the loop hands on.
    """
    schedule = goal_schedule(goals)
    tracking = {run_name: run_tracking_error(bag, schedule).to_json()
                for run_name, bag in bags.items()}
    sets = {'nominal': load_parameters(), 'identified': load_parameters(str(params_file))}
    if params_in_force != params_file:
        sets['calibrated'] = load_parameters(str(params_in_force))
    runs = {f'{run_name}_run': flow_prediction_error(bag, sets).to_json()
            for run_name, bag in bags.items()}
    in_force = 'calibrated' if 'calibrated' in sets else 'identified'
    after = runs['after_run']
    flow = {'before': {'params': 'nominal', **after['nominal']},
            'after': {'params': in_force, **after[in_force]},
            'record': 'after_run', 'full_flow_kg_s': after['full_flow_kg_s'], 'runs': runs}
    return _Evaluation(tracking, flow)


def run_operation_loop(out: Path, effect: str, effect_args: tuple[str, ...],
                       quick: bool = False,
                       plant_discharge_coefficient: float =
                       OPERATION_PLANT_DISCHARGE_COEFFICIENT) -> int:
    """The loop in service; writes ``out/loop.json`` and ``out/loop.md``.

    Returns the exit code: 0, or 1 when ``valve_simulator`` does not start with the set
    the loop hands on.

    Raises
    ------
    ValueError
        ``out`` already holds a run; a bag that cannot be analysed.
    RuntimeError
        A run of the suite or a command failed.
    """
    goals = OPERATION_QUICK_GOALS if quick else OPERATION_GOALS
    for sub in ('before', 'after'):
        if (out / sub / 'report').exists():
            raise ValueError(f'{out / sub} already holds a run; give another --out')
    stages = _Stages()
    plant = write_plant_parameters((out / 'plant_valve.yaml').resolve(),
                                   plant_discharge_coefficient)
    say(f'the valve in service: C_d {plant.discharge_coefficient:g} (the suite\'s set '
        f'says {plant.suite_discharge_coefficient:g}), {plant.params_file}')
    with stages.stage('run_before'):
        bag_before = _run_suite('before', out / 'before', effect_args, goals,
                                plant_params=plant.params_file)
    ident = out / 'identification'
    with stages.stage('identification'):
        report = identify(['--fit', str(bag_before)], ident, quick, effect)
    params = (ident / 'params.yaml').resolve()
    with stages.stage('map'):
        map_file = _build_map(params, out)
    with stages.stage('flow_calibration'):
        cal = _calibrate(bag_before, map_file, params,
                         (out / 'params_identified.yaml').resolve(), plant)
    with stages.stage('simulator_check'):
        sim_ok = simulator_starts(cal.params_file)
    if not sim_ok:
        return 1
    with stages.stage('run_after'):
        bag_after = _run_suite('after', out / 'after', effect_args, goals, flow_to_duty_args=(
            '-p', f'map_file:={map_file}', '-p', f'params_file:={cal.params_file}'),
            plant_params=plant.params_file)
    with stages.stage('evaluation'):
        ev = _evaluate({'before': bag_before, 'after': bag_after}, goals, params,
                       cal.params_file)
    diag = report['diagnosis']
    loop = {
        'mode': 'operation', 'effect_injected': effect, 'emulator_args': list(effect_args),
        'goals': [{'position_mm': g * 1e3, 'hold_s': h} for g, h in goals],
        'quick': quick,
        'diagnosis': diag,
        'judgement': {'expected': expected_answers(effect),
                      'right': diag.get('effect') in expected_answers(effect)},
        'baseline': error_figures(report['baseline']),
        'augmented': error_figures(report['augmented']),
        'identification': {'report': str(ident / 'report.md'), 'params': str(params),
                           'timings_s': report.get('timings_s', {})},
        'map': str(map_file), 'params_in_force': str(cal.params_file),
        'plant': plant.to_json(), 'flow_calibration': cal.report, 'simulator_started': sim_ok,
        'tracking': ev.tracking, 'flow': ev.flow, 'stages_s': stages.total(),
        'units': {'iae': 'A s', 'rmse': 'A', 'rms_mm': 'mm', 'rms_kg_s': 'kg/s',
                  'rms_pct': '% of full flow', 'stages_s': 's (wall time)'},
    }
    (out / 'loop.json').write_text(json.dumps(loop, indent=2, default=str) + '\n')
    (out / 'loop.md').write_text(loop_markdown(loop))
    _say_results(loop, out)
    return 0


def _say_results(loop: dict, out: Path) -> None:
    tracking, flow = loop['tracking'], loop['flow']
    say(f'tracking error (RMS goal - position): before {tracking["before"]["rms_mm"]:.3f} mm, '
        f'after {tracking["after"]["rms_mm"]:.3f} mm')
    say(f'flow prediction error (RMS, % of full flow, after run): nominal '
        f'{flow["before"]["rms_pct"]:.2f} %, identified {flow["after"]["rms_pct"]:.2f} %')
    say('stage times [s]: ' + ', '.join(f'{k} {v:.1f}' for k, v in loop['stages_s'].items()))
    say(f'loop report: {out / "loop.md"} (and loop.json)')
