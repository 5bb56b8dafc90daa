"""Bench records of the truth valve: ``pwm`` records through the drive electronics and
``step`` records of the bare coil, with the noise and quantisation a test asks for.

* ``pwm``: the bench drives the valve's electronics with a main PWM; the file carries the
  main PWM voltage (``voltage``: the supply while high, 0 V while low), the instantaneous
  coil current at 10-50 kHz and, if asked, the instantaneous terminal voltage
  (``coil_voltage``). The valve and electronics are those of :mod:`.operation`.
* ``step``: the bare coil under a 24 V fit step and a 15 V validation step (1-16 ms on,
  40 ms at 50 kHz, 4 and 3 bar) from the truth model's own solver (:mod:`.truth`), as
  :mod:`.generate` writes them, but with the noise of the test instead of the bench
  defaults and no missing samples.

The files are written in the shared format by :mod:`.csvfile`; nothing of the suite is
imported.
"""
from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from .csvfile import bench_current, write_table
from .electronics import Drive, DriveCircuit, DriveElectronics
from .generate import STEP_FIT, STEP_VALIDATE, FileSpec, effect_changes, effect_name
from .operation import PwmSchedule, default_schedule, electronics_of, simulate_operation
from .truth import TruthValve, perturbed, simulate_truth

__all__ = ['write_pwm_record', 'write_step_records', 'bench_valve', 'integration_step']

#: Integration steps tried, largest first, for a sample rate and a driver's clocks [s].
_STEPS_S = (25e-6, 12.5e-6, 10e-6, 5e-6, 2.5e-6)


def bench_valve(seed: int, effect: str, spread: float) -> TruthValve:
    """The paper's valve (``spread`` 0) or a seeded draw around it, with the effect on."""
    base = TruthValve()
    if spread > 0.0:
        base = perturbed(base, np.random.default_rng(seed), spread=spread)
    return replace(base, **effect_changes(effect))


def integration_step(electronics: DriveElectronics, rate_hz: float) -> float:
    """The largest step of :data:`_STEPS_S` that divides the sample period and every clock
    period of the driver [s]."""
    for step in _STEPS_S:
        per = 1.0 / (rate_hz * step)
        if abs(per - round(per)) > 1e-9:
            continue
        try:
            Drive(electronics, np.inf, step)
        except ValueError:
            continue
        return step
    raise ValueError(f'no integration step of {_STEPS_S} fits {rate_hz:g} Hz and the '
                     'driver\'s clocks')


def write_pwm_record(out_dir: str | Path, name: str = 'pwm', *, seed: int = 1,
                     effect: str = 'none', spread: float = 0.0,
                     valve: TruthValve | None = None,
                     circuit: DriveCircuit | DriveElectronics = DriveCircuit(),
                     frequency_hz: float = 50.0, duration_s: float = 0.4,
                     rate_hz: float = 20_000.0, noise_a: float = 0.0, lsb_a: float = 0.0,
                     adc_bits: int = 8, coil_voltage: bool = False,
                     schedule: PwmSchedule | None = None, supply_pa: float = 4e5
                     ) -> dict[str, object]:
    """Simulate a bench ``pwm`` record and write ``out_dir/name.csv`` and its truth JSON.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Directory for ``<name>.csv`` and ``<name>.truth.json``.
    name : str
        File stem.
    seed : int
        Seeds the valve draw (with ``spread``), the duty schedule and the noise.
    effect : str
        ``none``, a listed effect or ``coulomb_friction_stiction``.
    spread : float
        Relative spread of the Table 2 parameters (0: the paper's valve).
    valve : TruthValve, optional
        The valve itself (then ``seed``, ``spread`` and ``effect`` do not draw it).
    circuit : DriveCircuit or DriveElectronics
        The drive electronics.
    frequency_hz : float
        Main PWM frequency [Hz] (one frequency: the format's metadata carries it).
    duration_s : float
        Record length [s].
    rate_hz : float
        Sample rate of the current (and coil voltage) [Hz], 10-50 kHz.
    noise_a, lsb_a, adc_bits
        Gaussian noise [A] and quantisation of the current (:func:`.csvfile.bench_current`).
    coil_voltage : bool
        Add the instantaneous terminal voltage column ``coil_voltage`` [V].
    schedule : PwmSchedule, optional
        Main PWM periods (default: :func:`.operation.default_schedule` at ``frequency_hz``).
    supply_pa : float
        Supply pressure, gauge [Pa].

    Returns
    -------
    dict
        The truth JSON content.
    """
    rng = np.random.default_rng(seed)
    if valve is None:
        valve = bench_valve(seed, effect, spread)
    if schedule is None:
        schedule = default_schedule(duration_s, rng, frequency_hz=frequency_hz)
    electronics = electronics_of(circuit)
    step_s = integration_step(electronics, rate_hz)
    tr = simulate_operation(valve, schedule, duration_s, circuit=electronics,
                            supply_pa=supply_pa, sample_rate_hz=rate_hz, step_s=step_s)
    per = int(round(1.0 / (rate_hz * step_s)))
    idx = np.arange(0, tr.t_s.size, per)
    t = np.arange(idx.size) / rate_hz
    columns = {'t': t,
               'voltage': np.where(tr.main_pwm_high[idx], electronics.supply_voltage_v, 0.0),
               'current': bench_current(tr.current_a[idx], rng, noise_a, lsb_a, adc_bits)}
    if coil_voltage:
        columns['coil_voltage'] = tr.coil_voltage_v[idx]
    out = Path(out_dir)
    path = write_table(out / f'{name}.csv', {
        'experiment': 'pwm',
        'valve': f'generated valve ({effect}, seed {seed})',
        'supply_pressure_pa': supply_pa,
        'output_pressure_pa': 0,
        'pwm_frequency_hz': frequency_hz,
        'sample_rate_hz': rate_hz,
        'supply_voltage_v': electronics.supply_voltage_v,
        'generator': 'tests.datagen.bench (truth valve, own drive electronics)',
    }, columns)
    truth = {
        'file': str(path), 'experiment': 'pwm', 'effect': effect,
        'declared_effect': effect_name(effect), 'seed': seed, 'spread': spread,
        'valve': valve.as_dict(), 'electronics': electronics.describe(),
        'electronics_summary': electronics.summary(), 'noise_std_a': noise_a,
        'lsb_a': lsb_a, 'coil_voltage': coil_voltage, 'duration_s': duration_s,
        'rate_hz': rate_hz, 'step_s': step_s, 'supply_pressure_pa': supply_pa,
        'boosts_ended': len(tr.boost_ends_s), 'generation_wall_time_s': tr.wall_time_s,
    }
    (out / f'{name}.truth.json').write_text(json.dumps(truth, indent=2), encoding='utf-8')
    return truth


def _step_file(path: Path, spec: FileSpec, valve: TruthValve, rng: np.random.Generator,
               noise_a: float, lsb_a: float, adc_bits: int, label: str) -> dict[str, object]:
    n = int(round(spec.duration_s * spec.rate_hz))
    t = np.arange(n) / spec.rate_hz
    trace = simulate_truth(valve, spec.segments(), t[-1], t, spec.supply_pa)
    write_table(path, {
        'experiment': 'step',
        'valve': f'generated valve ({label})',
        'supply_pressure_pa': spec.supply_pa,
        'output_pressure_pa': 0,
        'supply_temperature_k': 293.15,
        'sample_rate_hz': spec.rate_hz,
        'generator': 'tests.datagen.bench (truth model, see truth.json)',
    }, {'t': t, 'voltage': trace.voltage_cmd_v,
        'current': bench_current(trace.current_a, rng, noise_a, lsb_a, adc_bits)})
    moving = np.flatnonzero(trace.position_m > 1e-7)
    return {'file': str(path), 'voltage_v': spec.voltage_v,
            'supply_pressure_pa': spec.supply_pa,
            'motion_start_s': float(t[moving[0]]) if moving.size else None,
            'closed_at_end': bool(trace.position_m[-1] < 1e-7)}


def write_step_records(out_dir: str | Path, name: str = 'step', *, seed: int = 1,
                       effect: str = 'coulomb_friction_stiction', spread: float = 0.0,
                       valve: TruthValve | None = None, noise_a: float = 3e-3,
                       lsb_a: float = 0.0, adc_bits: int = 8) -> dict[str, object]:
    """Write ``out_dir/name_fit_24v.csv`` and ``out_dir/name_validate_15v.csv``.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Directory of the files and ``<name>.truth.json``.
    name : str
        File stem.
    seed : int
        Seeds the valve draw (with ``spread``) and the noise.
    effect : str
        ``none``, a listed effect or ``coulomb_friction_stiction`` (2 N sliding, 2.5 N
        stiction).
    spread : float
        Relative spread of the Table 2 parameters (0: the paper's valve).
    valve : TruthValve, optional
        The valve itself (then ``seed``, ``spread`` and ``effect`` do not draw it).
    noise_a, lsb_a, adc_bits
        Gaussian noise [A] and quantisation of the current (:func:`.csvfile.bench_current`).

    Returns
    -------
    dict
        The truth JSON content, with ``fit`` and ``validate`` lists of paths.
    """
    rng = np.random.default_rng(seed)
    if valve is None:
        valve = bench_valve(seed, effect, spread)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    label = f'{effect}, seed {seed}'
    fit = _step_file(out / f'{name}_fit_24v.csv', STEP_FIT, valve, rng, noise_a, lsb_a,
                     adc_bits, label)
    validate = _step_file(out / f'{name}_validate_15v.csv', STEP_VALIDATE, valve, rng,
                          noise_a, lsb_a, adc_bits, label)
    truth = {
        'experiment': 'step', 'effect': effect, 'declared_effect': effect_name(effect),
        'seed': seed, 'spread': spread, 'valve': valve.as_dict(),
        'noise_std_a': noise_a, 'lsb_a': lsb_a, 'files': {'fit': fit, 'validate': validate},
        'fit': [fit['file']], 'validate': [validate['file']],
        'specs': [asdict(STEP_FIT), asdict(STEP_VALIDATE)],
    }
    (out / f'{name}.truth.json').write_text(json.dumps(truth, indent=2), encoding='utf-8')
    return truth
