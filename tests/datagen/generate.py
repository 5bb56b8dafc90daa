"""Write fit and validation data sets in the shared CSV format from the truth model.

Each *case* is one valve instance (parameters drawn around Table 2, seeded), at most one
effect switched on, and realistic bench noise:

* Gaussian current noise with a standard deviation of 0.5 % of the current channel's full
  scale (bipolar +-2.5 A), then 12-bit quantisation of that range;
* a few missing samples: rows left out of the file (gaps in ``t``) and rows whose current
  field is empty, as the format document warns.

Files per case (the names say what the bench did):

==========================  ==============================================================
``fit_24v_step.csv``        24 V from 1 ms to 16 ms, 0 V after, 40 ms at 50 kHz, 4 bar
``validate_15v_step.csv``   15 V from 1 ms to 16 ms, 0 V after, 40 ms at 50 kHz, 3 bar
``fit_24v_long.csv``        24 V for 2.5 s, 0 V for 0.1 s, at 5 kHz, 4 bar (``long``)
``validate_15v_long.csv``   15 V for 2.5 s, 0 V for 0.1 s, at 5 kHz, 3 bar (``long``)
==========================  ==============================================================

The long files are written for ``coil_heating`` (which needs seconds to show) and on
request for any other case. Each case directory also holds ``truth.json`` with the valve
instance and the effect, for the tests (the identification never reads it).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .truth import TruthValve, perturbed, simulate_truth

#: Effects the identification declares, plus ``none`` and the undeclared one.
LISTED_EFFECTS = ('magnetic_saturation', 'eddy_current', 'coulomb_friction', 'coil_heating',
                  'leakage_inductance', 'end_stop_bounce')
OUTSIDE_EFFECT = 'supply_ripple'
#: A second effect outside the list, of another form (a drop in the voltage balance).
OUTSIDE_EFFECT_2 = 'diode_drop'
CASES = ('paper', 'none') + LISTED_EFFECTS + (OUTSIDE_EFFECT, OUTSIDE_EFFECT_2)

FULL_SCALE_A = 2.5
NOISE_FRACTION = 0.005
ADC_BITS = 12


@dataclass(frozen=True)
class FileSpec:
    """One bench experiment: a voltage pulse, sampled."""

    name: str
    voltage_v: float
    on_s: float
    off_s: float
    duration_s: float
    rate_hz: float
    supply_pa: float

    def segments(self) -> list[tuple[float, float]]:
        return [(0.0, 0.0), (self.on_s, self.voltage_v), (self.off_s, 0.0)]


STEP_FIT = FileSpec('fit_24v_step', 24.0, 1e-3, 16e-3, 40e-3, 50e3, 4e5)
STEP_VALIDATE = FileSpec('validate_15v_step', 15.0, 1e-3, 16e-3, 40e-3, 50e3, 3e5)
LONG_FIT = FileSpec('fit_24v_long', 24.0, 2e-3, 2.502, 2.6, 5e3, 4e5)
LONG_VALIDATE = FileSpec('validate_15v_long', 15.0, 2e-3, 2.502, 2.6, 5e3, 3e5)


def effect_changes(effect: str) -> dict[str, float]:
    """Truth-model fields that switch one effect on, at a size a bench would notice."""
    table = {
        'paper': {},
        'none': {},
        'magnetic_saturation': {'saturation_current_a': 2.6},
        'eddy_current': {'eddy_resistance_ohm': 250.0},
        'coulomb_friction': {'friction_n': 2.0},
        'coulomb_friction_stiction': {'friction_n': 2.0, 'stiction_n': 2.5},
        'coil_heating': {'thermal_capacity_j_k': 6.0, 'thermal_resistance_k_w': 15.0},
        'leakage_inductance': {'leakage_inductance_h': 0.02},
        'end_stop_bounce': {'restitution': 0.5},
        'supply_ripple': {'ripple_fraction': 0.08, 'ripple_hz': 100.0,
                          'source_resistance_ohm': 0.3},
        'diode_drop': {'diode_drop_v': 1.0, 'diode_knee_a': 0.02},
    }
    if effect not in table:
        raise ValueError(f'unknown case {effect!r}; choose from {sorted(table)}')
    return table[effect]


#: Variants of a listed effect (another form or size of it), by the listed name they are.
EFFECT_VARIANTS = {'coulomb_friction_stiction': 'coulomb_friction'}


def effect_name(effect: str) -> str:
    """The listed effect (or ``none``) that an effect or a variant of it is."""
    if effect in ('none', 'paper'):
        return 'none'
    return EFFECT_VARIANTS.get(effect, effect)


def case_valve(case: str, seed: int) -> TruthValve:
    """The valve instance of a case: Table 2 for ``paper``, a seeded instance otherwise."""
    base = TruthValve()
    if case != 'paper':
        base = perturbed(base, np.random.default_rng(seed), spread=0.10)
    return replace(base, **effect_changes(case))


def bench_noise(current_a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Add 0.5 %-of-full-scale Gaussian noise and quantise to 12 bits over +-full scale."""
    noisy = current_a + rng.normal(0.0, NOISE_FRACTION * FULL_SCALE_A, current_a.shape)
    lsb = 2.0 * FULL_SCALE_A / 2 ** ADC_BITS
    return np.clip(np.round(noisy / lsb) * lsb, -FULL_SCALE_A, FULL_SCALE_A - lsb)


def write_trace(path: Path, spec: FileSpec, valve: TruthValve, rng: np.random.Generator,
                *, case: str, missing: bool = True) -> dict[str, object]:
    """Simulate one experiment on ``valve`` and write it; returns facts for truth.json."""
    # Sample times as the bench's clock gives them: n / rate, so no float drift.
    n = int(round(spec.duration_s * spec.rate_hz))
    t = np.arange(n) / spec.rate_hz
    trace = simulate_truth(valve, spec.segments(), t[-1], t, spec.supply_pa)
    current = bench_noise(trace.current_a, rng)
    keep = np.ones(n, dtype=bool)
    if missing:
        # About one row in a thousand lost (never at the very start), and two empty fields.
        lost = rng.choice(np.arange(5, n), size=max(1, n // 1000), replace=False)
        keep[lost] = False
        empty = rng.choice(np.flatnonzero(keep)[5:], size=2, replace=False)
        current[empty] = math.nan
    meta = {
        'experiment': 'step',
        'valve': f'generated valve ({case})',
        'supply_pressure_pa': f'{spec.supply_pa:g}',
        'output_pressure_pa': '0',
        'supply_temperature_k': '293.15',
        'sample_rate_hz': f'{spec.rate_hz:g}',
        'generator': 'tests.datagen (truth model, see truth.json)',
    }
    _write_csv(path, t[keep], trace.voltage_cmd_v[keep], current[keep], meta)
    moving = np.flatnonzero(trace.position_m > 1e-7)
    return {
        'file': path.name, 'voltage_v': spec.voltage_v, 'supply_pressure_pa': spec.supply_pa,
        'rows': int(keep.sum()), 'rows_left_out': int((~keep).sum()),
        'motion_start_s': float(t[moving[0]]) if moving.size else None,
        'motion_end_s': float(t[moving[-1]]) if moving.size else None,
        'closed_at_end': bool(trace.position_m[-1] < 1e-7),
        'max_temperature_rise_k': float(trace.temperature_rise_k.max()),
    }


def _write_csv(path: Path, t: np.ndarray, v: np.ndarray, i: np.ndarray,
               meta: dict[str, str]) -> None:
    """The shared CSV format, written here without the package (keeps the tests honest)."""
    lines = [f'# {k}: {val}' for k, val in meta.items()]
    lines.append('t,voltage,current')
    for tt, vv, ii in zip(t, v, i):
        lines.append(f'{tt:.8g},{vv:.6g},{"" if math.isnan(ii) else f"{ii:.6g}"}')
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')


def generate_case(out_dir: str | Path, case: str, *, seed: int = 1, long: bool | None = None,
                  step_duration_s: float | None = None) -> dict[str, object]:
    """Write the data set of one case into ``out_dir/case``.

    Parameters
    ----------
    out_dir : str or pathlib.Path
        Parent directory; the case gets a sub-directory of its name.
    case : str
        ``paper``, ``none``, one of :data:`LISTED_EFFECTS`, ``supply_ripple`` or
        ``diode_drop``.
    seed : int
        Seeds the valve instance and the noise (different cases with one seed still get
        different valves: the case name is mixed in).
    long : bool, optional
        Write the multi-second files; by default only for ``coil_heating``.
    step_duration_s : float, optional
        Length of the step files (default 40 ms).

    Returns
    -------
    dict
        The content of ``truth.json``: case, effect, valve parameters, files (fit and
        validation lists of paths).
    """
    case_seed = seed * 1000 + CASES.index(case)
    rng = np.random.default_rng(case_seed)
    valve = case_valve(case, case_seed)
    directory = Path(out_dir) / case
    directory.mkdir(parents=True, exist_ok=True)
    with_long = case == 'coil_heating' if long is None else long
    specs_fit = [STEP_FIT] + ([LONG_FIT] if with_long else [])
    specs_val = [STEP_VALIDATE] + ([LONG_VALIDATE] if with_long else [])
    if step_duration_s is not None:
        specs_fit[0] = replace(STEP_FIT, duration_s=step_duration_s)
        specs_val[0] = replace(STEP_VALIDATE, duration_s=step_duration_s)
    files: dict[str, list[dict[str, object]]] = {'fit': [], 'validate': []}
    for role, specs in (('fit', specs_fit), ('validate', specs_val)):
        for spec in specs:
            path = directory / f'{spec.name}.csv'
            files[role].append(write_trace(path, spec, valve, rng, case=case))
    truth = {
        'case': case,
        'effect': case if case in LISTED_EFFECTS else 'none' if case in ('none', 'paper')
        else f'outside:{case}',
        'seed': seed,
        'valve': valve.as_dict(),
        'files': files,
        'fit': [str(directory / f['file']) for f in files['fit']],
        'validate': [str(directory / f['file']) for f in files['validate']],
        'noise': {'std_a': NOISE_FRACTION * FULL_SCALE_A, 'full_scale_a': FULL_SCALE_A,
                  'adc_bits': ADC_BITS},
    }
    (directory / 'truth.json').write_text(json.dumps(truth, indent=2), encoding='utf-8')
    return truth
