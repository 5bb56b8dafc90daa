"""Identification benchmarks: speed of the fit and of the whole loop, accuracy.

Writes benchmarks/results/identify.json (records: name, value, unit, reference_name,
reference_value, ratio, target, passed, notes).

1. ``identify_8_params_40ms_50khz``: the baseline fit of the eight Table 2 parameters from
   a 40 ms, 50 kHz noisy 24 V step (full effort), target <= 30 s on 2 cores.
2. ``close_the_loop_40ms``: baseline, residual analysis, signatures, six refits and the
   selection on a 40 ms fit file + a 40 ms validation file, target <= 180 s.
3. ``table2_recovery_worst_pinned_pct``: the largest relative error of a pinned-down
   parameter after (1), target <= 5 %.
4. ``close_the_loop_diagnosis_correct``: how many of the generated cases (none, six
   effects, one outside the list) the loop answers right (informative).
5. ``identify_operation_10s_1khz``: baseline and drive electronics from a 10 s
   operational record at 1 kHz, target <= 60 s on 2 cores.
6. ``close_the_loop_60ms_pair_plus_3s_record``: the whole loop on a 60 ms step pair plus a
   3 s operational record, target <= 60 s on 2 cores.
7. ``operation_parameter_error_worst_pct``: error of each parameter identified from 2 s
   operational records of valves with known parameters (made with the suite's model).

The data come from the test-data generator (tests/datagen), run here into a temporary
folder. The first simulation compiles the numba kernels; that is timed separately
(``numba_warmup``) and not counted in (1) and (2).
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path
from common import record as _record, write_results  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / 'valve_model_pkg'))
sys.path.insert(0, str(ROOT / 'tests'))

from datagen.generate import CASES, LISTED_EFFECTS, generate_case  # noqa: E402
from valve_model_pkg.identification.csv_reader import read_csv  # noqa: E402
from valve_model_pkg.identification import IdentifySettings, identify  # noqa: E402
from valve_model_pkg.identification.problem import equivalent_gap_m  # noqa: E402
from valve_model_pkg.model.parameters import load_parameters  # noqa: E402

_TRUTH = {'coil_resistance_ohm': 'resistance_ohm', 'stroke_m': 'stroke_m',
          'core_area_m2': 'flux_area_m2', 'spring_pretension_m': 'pretension_m'}


def _write_operation(path: Path, params, duration_s: float, noise_a: float, seed: int,
                     phase_s: float = 0.0073) -> Path:
    """An operation record at 1 kHz (interval means) of ``params`` with the electronics on.

    Made with the suite's own model (the truth model of tests/datagen has no drive
    electronics yet): it measures speed and the recovery of known parameters through the
    electronics, not independence from the model.
    """
    import numpy as np
    from valve_model_pkg.dataformat import write_table
    from valve_model_pkg.model import InputTrace, simulate_trace_batch
    rng = np.random.default_rng(seed)
    t_cmd, duty, freq = [0.0], [0.0], [1.0 / phase_s]
    s = phase_s
    while s < duration_s:
        d = 0.0 if s < 0.04 else [0.2, 0.5, 0.8, 0.35, 0.65][int(s / 0.2) % 5]
        t_cmd.append(s - 1e-6)
        duty.append(d)
        freq.append(50.0)
        s += 0.02
    trace = InputTrace.pwm_commands(t_cmd, duty, freq, 24.0)
    t = np.arange(1, int(round(duration_s * 1000)) + 1) * 1e-3
    res = simulate_trace_batch(params, trace, t, sampling='interval_mean',
                               supply_pressure_pa=4e5)
    starts = np.array(t_cmd[1:]) + 1e-6
    k = np.searchsorted(starts, t, side='right') - 1
    d_in = np.where(k >= 0, np.array(duty[1:])[np.clip(k, 0, None)], 0.0)
    return write_table(path, {
        'experiment': 'operation', 'supply_voltage_v': 24, 'sample_rate_hz': 1000,
        'current_averaging': 'interval_mean', 'supply_pressure_pa': 400000},
        {'t': t, 'duty': d_in, 'pwm_frequency_hz': np.full(t.size, 50.0),
         'current': res.coil_current_a[0] + rng.normal(0.0, noise_a, t.size)})


def _operation_records(tmp: str, base, load: str) -> list[dict]:
    """A 10 s operational record, the close-the-loop run on a 60 ms step pair
    plus a 3 s record, and the per-parameter error on records with known truth."""
    import numpy as np
    from valve_model_pkg.identification.readers import read_measurements
    out = []
    rec = _write_operation(Path(tmp) / 'ops10.csv', base, 10.0, 3e-3, 1)
    t0 = time.perf_counter()
    ident = identify(read_measurements([rec]), [], IdentifySettings(diagnose=False), base=base)
    t_ops = time.perf_counter() - t0
    out.append(_record(
        'identify_operation_10s_1khz', t_ops, 's', 'target', 60.0, '<= 60 s on 2 cores',
        t_ops <= 60.0, f'baseline + drive electronics from a 10 s operational record at '
        f'1 kHz (fit on 1 s of the first 70 %, hold-out the last 30 %); '
        f'{ident.simulations} simulations; {load}'))
    steps = generate_case(tmp, 'none', seed=11, step_duration_s=0.06)
    rec3 = _write_operation(Path(tmp) / 'ops3.csv', base, 3.0, 3e-3, 2)
    t0 = time.perf_counter()
    ident = identify(read_measurements(steps['fit'] + [str(rec3)]),
                     read_measurements(steps['validate']), IdentifySettings(), base=base)
    t_loop = time.perf_counter() - t0
    out.append(_record(
        'close_the_loop_60ms_pair_plus_3s_record', t_loop, 's', 'target', 60.0,
        '<= 60 s on 2 cores', t_loop <= 60.0, f'diagnosis {ident.diagnosis.effect} '
        f'({ident.diagnosis.confidence}); {ident.simulations} simulations; time split: '
        + ', '.join(f'{k} {v:.1f} s' for k, v in ident.timings_s.items()) + f'; {load}'))
    errs: dict[str, list[float]] = {}
    names = ('coil_resistance_ohm', 'stroke_m', 'core_area_m2', 'spring_pretension_m',
             'damping_n_s_per_m')
    rng = np.random.default_rng(7)
    for k in range(2):
        truth = base.replace(**{n: getattr(base, n) * (1 + rng.uniform(-0.1, 0.1))
                                for n in names})
        rec = _write_operation(Path(tmp) / f'opsT{k}.csv', truth, 2.0, 3e-3, 10 + k)
        ident = identify(read_measurements([rec]), [],
                         IdentifySettings(quick=True, diagnose=False), base=base)
        p = ident.baseline.params
        for n in names:
            errs.setdefault(n, []).append(100 * abs(getattr(p, n) / getattr(truth, n) - 1))
        errs.setdefault('equivalent_gap_m', []).append(
            100 * abs(equivalent_gap_m(p) / equivalent_gap_m(truth) - 1))
    worst = max(max(v) for n, v in errs.items() if n != 'damping_n_s_per_m')
    out.append(_record(
        'operation_parameter_error_worst_pct', worst, '%', 'target', 5.0,
        'informative (<= 5 % for R, x_max, A_e, delta, s)', worst <= 5.0,
        'per parameter, max over 2 records (suite model, +-10 % valves, 3 mA noise): '
        + ', '.join(f'{n} {max(v):.2f} %' for n, v in errs.items())))
    return out


def main() -> int:
    load = f'machine load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs'
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        base = load_parameters()
        paper = generate_case(tmp, 'paper', seed=1)
        fit = [read_csv(f) for f in paper['fit']]
        val = [read_csv(f) for f in paper['validate']]
        t0 = time.perf_counter()
        identify(fit, val, IdentifySettings(quick=True, diagnose=False), base=base)
        warm = time.perf_counter() - t0
        records.append(_record('numba_warmup', warm, 's', None, None, 'informative', True,
                               'first run in a fresh process: kernel compilation or cache '
                               f'load, plus a quick fit; {load}'))

        t0 = time.perf_counter()
        ident = identify(fit, val, IdentifySettings(diagnose=False), base=base)
        t_fit = ident.timings_s['baseline_fit']
        records.append(_record(
            'identify_8_params_40ms_50khz', t_fit, 's', 'target', 30.0, '<= 30 s on 2 cores',
            t_fit <= 30.0, f'{ident.simulations} simulations; full effort (256 Sobol points, '
            f'6 lock-step Nelder-Mead starts); {load}'))
        p, tv = ident.baseline.params, paper['valve']
        errs = {n: abs(getattr(p, n) / tv[k] - 1.0) * 100 for n, k in _TRUTH.items()}
        s_true = tv['core_length_m'] / tv['mu_r'] + 2 * tv['total_gap_m']
        errs['equivalent_gap_m'] = abs(equivalent_gap_m(p) / s_true - 1.0) * 100
        pinned = ident.baseline.sensitivity.pinned
        worst = max(errs[n] for n in pinned if n in errs)
        records.append(_record(
            'table2_recovery_worst_pinned_pct', worst, '%', 'target', 5.0, '<= 5 %',
            worst <= 5.0, 'errors: ' + ', '.join(f'{n} {e:.2f} %' for n, e in errs.items())
            + f'; pinned down: {pinned}; not: {ident.baseline.sensitivity.not_pinned}'))

        case = generate_case(tmp, 'coulomb_friction', seed=3)
        fit = [read_csv(f) for f in case['fit']]
        val = [read_csv(f) for f in case['validate']]
        t0 = time.perf_counter()
        ident = identify(fit, val, IdentifySettings(), base=base)
        t_loop = time.perf_counter() - t0
        records.append(_record(
            'close_the_loop_40ms', t_loop, 's', 'target', 180.0, '<= 180 s on 2 cores',
            t_loop <= 180.0, f'coulomb_friction case: diagnosis {ident.diagnosis.effect}; '
            f'{ident.simulations} simulations; stages {ident.timings_s}; {load}'))

        right = []
        for name in CASES[1:]:
            c = generate_case(tmp, name, seed=5)
            res = identify([read_csv(f) for f in c['fit']],
                           [read_csv(f) for f in c['validate']], IdentifySettings(), base=base)
            want = name if name in LISTED_EFFECTS else 'none'
            ok = res.diagnosis.effect == want or (
                name not in LISTED_EFFECTS and name != 'none'
                and (res.diagnosis.confidence == 'low'
                     or res.diagnosis.effect == 'unlisted'))
            right.append(f'{name}: {res.diagnosis.effect} ({res.diagnosis.confidence}) '
                         f'{"ok" if ok else "WRONG"}, validation RMSE '
                         f'{1e3 * res.baseline.validation.rmse:.2f} -> '
                         f'{1e3 * res.augmented.validation.rmse:.2f} mA')
            print(right[-1], file=sys.stderr)
        n_ok = sum(r.count(' ok,') for r in right)
        records.append(_record(
            'close_the_loop_diagnosis_correct', float(n_ok), 'cases', 'cases', float(len(right)),
            'informative', n_ok == len(right), '; '.join(right)))
        records += _operation_records(tmp, base, load)
    write_results('identify', records)
    for r in records:
        print(f"{r['name']}: {r['value']:.4g} {r['unit']} (target {r['target']}) "
              f"{'ok' if r['passed'] else 'MISSED'}", file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
