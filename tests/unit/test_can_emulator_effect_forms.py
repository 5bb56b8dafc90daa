"""The emulator's effect forms that are not the identification's candidate equations.

The emulated valve must be able to carry an effect written independently
of the candidate forms the identification adds back, so a loop test that names the effect
is not circular. ``parameters.EMULATOR_EFFECTS`` holds two such forms (``saturation_tanh``,
``eddy_ladder``; docs/effects.md). Checked here:

* off (the default) leaves the kernel bit-identical (a digest of simulate_trace_batch
  outputs recorded from the kernel without the forms);
* each form changes the 1 kHz interval-mean current of a 0.8 s, 24 V bench step visibly;
* each form is not its candidate's equation: the candidate with its best constant (a 1-D
  search over its one parameter) leaves a residual far above the candidate-on-its-own
  case and far above what bench noise could hide;
* the forms are not identification candidates, and the emulator's ``--effect`` selects them.
"""
from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from valve_driver_pkg.emulator.emulator_main import apply_effects, build_parser
from valve_model_pkg.model import (
    EFFECTS, ElectronicsConfig, InputTrace, ValveParameters, ValveStepper, simulate_trace_batch,
)
from valve_model_pkg.model.parameters import EMULATOR_EFFECTS

P = ValveParameters()
T = np.arange(1, 801) * 1e-3                       # 0.8 s of 1 kHz telemetry
STEP = InputTrace.coil_voltage([0.0, 0.01], [0.0, 24.0])
#: Bench current noise of tests/datagen (0.5 % of a 2.5 A full scale), A.
NOISE_STD_A = 0.0125

#: SHA-256 of the outputs below computed by a kernel without the emulator forms (same
#: inputs). Off must stay bit-identical; a deliberate change of the kernel's arithmetic
#: has to regenerate it (hash _off_outputs of the changed kernel).
OFF_DIGEST = 'bccc621922f3d9e2feddd5acdc26a8752e50952e7441165e379c9cdd1d8e1fa6'


def _off_outputs() -> dict[str, np.ndarray]:
    sets = [P, P.replace(saturation_coefficient_per_a=0.5), P.replace(eddy_conductance_s=0.01),
            P.replace(coulomb_friction_n=1.0), P.replace(thermal_resistance_k_per_w=100.0),
            P.replace(leakage_inductance_h=0.02), P.replace(restitution_coefficient=0.5), P]
    step = InputTrace.coil_voltage([0.0, 0.4], [24.0, 0.0])
    pwm = InputTrace.pwm_commands([0.0, 0.2, 0.5], duty=[0.3, 0.7, 0.0])
    out = {}
    for name, trace in (('step', step), ('pwm', pwm)):
        for sampling in ('instant', 'interval_mean'):
            res = simulate_trace_batch(sets, trace, T, sampling=sampling)
            for field in ('coil_current_a', 'spool_position_m', 'n_steps'):
                out[f'{name}_{sampling}_{field}'] = np.asarray(getattr(res, field), float)
    return out


def _current(params: list[ValveParameters]) -> np.ndarray:
    return simulate_trace_batch(params, STEP, T, sampling='interval_mean').coil_current_a


def _fit_1d(target: np.ndarray, field: str, low: float, high: float) -> tuple[float, float]:
    """Best value of one parameter (grid of 17, zoomed twice) and its RMS residual, A."""
    for _ in range(3):
        values = np.linspace(low, high, 17)
        cur = _current([P.replace(**{field: float(v)}) for v in values])
        rms = np.sqrt(np.mean((cur - target) ** 2, axis=1))
        k = int(np.argmin(rms))
        width = values[1] - values[0]
        low, high = max(values[0], values[k] - width), min(values[-1], values[k] + width)
    return float(values[k]), float(rms[k])


def _demo(name: str) -> ValveParameters:
    return P.replace(**EMULATOR_EFFECTS[name].demo)


def test_off_is_bit_identical_to_the_kernel_before_the_forms() -> None:
    out = _off_outputs()
    digest = hashlib.sha256()
    for key in sorted(out):
        digest.update(np.ascontiguousarray(out[key], dtype='<f8').tobytes())
    assert digest.hexdigest() == OFF_DIGEST
    # the ladder's shunt resistance alone (ratio 0) switches nothing on: max difference 0.0
    idle = P.replace(eddy_ladder_resistance_ohm=55.0)
    assert idle.active_effects() == ()
    res = _current([P, idle])
    assert np.max(np.abs(res[0] - res[1])) == 0.0


# form -> (candidate field, its 1-D search range, a candidate value for the own case)
CANDIDATE_OF = {
    'saturation_tanh': ('saturation_coefficient_per_a', (0.0, 2.0), 0.173),
    'eddy_ladder': ('eddy_conductance_s', (0.0, 0.02), 0.00731),
}


@pytest.mark.parametrize('form', sorted(EMULATOR_EFFECTS))
def test_form_is_visible_and_not_the_candidate_equation(form: str) -> None:
    assert set(CANDIDATE_OF) == set(EMULATOR_EFFECTS)
    field, (low, high), own_value = CANDIDATE_OF[form]
    base, emulated, own = _current([P, _demo(form), P.replace(**{field: own_value})])
    effect = emulated - base
    final = base[-1]
    # visible: several % of the 1.85 A final current in the 1 kHz interval means
    assert np.max(np.abs(effect)) > 0.04 * final, form
    assert abs(emulated[-1] - final) < 1e-6 * final  # a transient effect, as designed
    # the candidate refits its own data to the search's resolution ...
    _, own_rms = _fit_1d(own, field, low, high)
    # ... but not the form's: best 1-D fit of the candidate to the emulated current
    best, rms = _fit_1d(emulated, field, low, high)
    effect_rms = float(np.sqrt(np.mean(effect ** 2)))
    assert low < best < high, (form, best)         # the candidate does try (interior optimum)
    assert rms > 30.0 * own_rms, (form, rms, own_rms)
    assert rms > 0.15 * effect_rms, (form, rms, effect_rms)   # > 2 % of the energy left
    # beyond noise: the systematic residual's chi-square under bench noise is far above
    # what 800 noise samples give (800 +- 40)
    assert T.size * rms ** 2 / NOISE_STD_A ** 2 > 100.0, (form, rms)


def test_forms_are_not_identification_candidates() -> None:
    from valve_model_pkg.identification import diagnosis

    assert not set(EMULATOR_EFFECTS) & set(EFFECTS)
    candidate_fields = {f for spec in EFFECTS.values() for f in spec.fields}
    for name, spec in EMULATOR_EFFECTS.items():
        assert not set(spec.fields) & candidate_fields, name
        assert all(getattr(P, f) == spec.neutral[f] for f in spec.fields), name
        assert _demo(name).active_effects() == (name,)
    assert diagnosis.EFFECTS is EFFECTS    # the candidates come from EFFECTS only


def test_parameter_files_carry_a_form_only_when_set() -> None:
    assert set(P.to_dict()['effects']) == set(EFFECTS)
    ladder = _demo('eddy_ladder')
    data = ladder.to_dict()
    assert data['effects']['eddy_ladder'] == EMULATOR_EFFECTS['eddy_ladder'].demo
    assert ValveParameters.from_dict(data) == ladder


def test_emulator_effect_option_selects_the_forms() -> None:
    assert apply_effects(P, ['saturation_tanh'], []) == _demo('saturation_tanh')
    both = apply_effects(P, ['eddy_ladder', 'saturation_tanh'],
                         ['eddy_ladder_resistance_ohm=35'])
    assert both.eddy_ladder_resistance_ohm == 35.0
    assert set(both.active_effects()) == {'eddy_ladder', 'saturation_tanh'}
    with pytest.raises(ValueError, match='not a parameter of the effects'):
        apply_effects(P, ['eddy_current'], ['eddy_ladder_inductance_ratio=1'])
    text = build_parser().format_help()
    for name in EMULATOR_EFFECTS:
        assert name in text
    assert 'independently' in text


def test_stepper_runs_a_form_as_the_batch_does() -> None:
    """The CAN emulator's ValveStepper integrates the ladder's extra current too."""
    params = _demo('eddy_ladder')
    means = []
    bare = dataclasses.replace(ElectronicsConfig(), current_control=False,
                               negative_voltage=False)
    for p in (P, params):
        stepper = ValveStepper(p, bare, supply_voltage_v=24.0)
        stepper.set_command(1.0, 1.0)
        stepper.advance_to(0.005)
        stepper.interval_means()
        stepper.advance_to(0.006)
        means.append(stepper.interval_means()[0])
    assert abs(means[1] - means[0]) > 0.01, means
