"""An effect amount beyond its default search bound is found by widening the bound.

The record comes from the independent truth model (tests/datagen): the paper's valve with
7 N Coulomb friction (the registry's search bound is 3 N; the spring's closing force
k delta = 11 N is the physical limit), a 24 V step at 4 bar, 50 kHz, with bench noise. The
friction refit starts from the truth's own Table 2 values (no baseline search) at the
quick effort: it must reach the 3 N bound, say that it widened it to 9 N, and land near
the 7 N of the truth. A refit that ends inside its bound is returned unchanged.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from datagen.generate import FileSpec, write_trace
from datagen.truth import TruthValve
from valve_model_pkg.identification import read_measurements
from valve_model_pkg.identification.diagnosis import (
    RefitResult, refit_effect, widen_at_bound,
)
from valve_model_pkg.identification.pipeline import QUICK_REFIT_EFFORT
from valve_model_pkg.identification.problem import (
    FitData, amount_limit, baseline_space, coarse_data, effect_space,
)
from valve_model_pkg.model.parameters import EFFECTS, ValveParameters

TRUTH_FRICTION_N = 7.0

#: Truth-model field -> ValveParameters field (Tables 1 and 2).
_FIELDS = {'spool_mass_kg': 'spool_mass_kg', 'spring_n_m': 'spring_stiffness_n_per_m',
           'turns': 'coil_turns', 'area1_m2': 'area_a1_m2', 'area2_m2': 'area_a2_m2',
           'core_length_m': 'core_length_m', 'resistance_ohm': 'coil_resistance_ohm',
           'stroke_m': 'stroke_m', 'flux_area_m2': 'core_area_m2',
           'pretension_m': 'spring_pretension_m', 'total_gap_m': 'total_air_gap_m',
           'damping_n_s_m': 'damping_n_s_per_m', 'mu_r': 'relative_permeability'}


@pytest.fixture(scope='module')
def friction_record(tmp_path_factory: pytest.TempPathFactory) -> tuple[FitData, TruthValve]:
    valve = replace(TruthValve(), friction_n=TRUTH_FRICTION_N)
    spec = FileSpec('fit_24v_step', 24.0, 1e-3, 16e-3, 40e-3, 50e3, 4e5)
    path = tmp_path_factory.mktemp('bound') / f'{spec.name}.csv'
    facts = write_trace(path, spec, valve, np.random.default_rng(7), case='friction_7n')
    assert facts['motion_start_s'] is not None and facts['closed_at_end'], facts
    return FitData(read_measurements([path])), valve


def _truth_params(valve: TruthValve) -> ValveParameters:
    return ValveParameters().replace(**{p: float(getattr(valve, t)) for t, p in _FIELDS.items()})


def test_friction_beyond_its_search_bound_is_found_by_widening(friction_record) -> None:
    fit, valve = friction_record
    params = _truth_params(valve)
    default_high = EFFECTS['coulomb_friction'].bounds['coulomb_friction_n'][1]
    assert TRUTH_FRICTION_N > default_high
    assert amount_limit('coulomb_friction_n', params).value > TRUTH_FRICTION_N
    r = refit_effect(baseline_space(params), coarse_data(fit).serial(), params,
                     'coulomb_friction', QUICK_REFIT_EFFORT)
    assert r.widened, 'the refit did not report reaching its bound'
    assert r.widened[0].startswith(
        f'coulomb_friction_n reached its search bound {default_high:g} N: widened to 9 N')
    assert r.params.coulomb_friction_n == pytest.approx(TRUTH_FRICTION_N, rel=0.1)
    assert r.space.bounds[r.space.names.index('coulomb_friction_n')].high > default_high


def test_a_refit_inside_its_bound_is_returned_unchanged(friction_record) -> None:
    fit, valve = friction_record
    params = _truth_params(valve).replace(coulomb_friction_n=2.0)
    ext = effect_space(baseline_space(params), 'coulomb_friction')
    inside = RefitResult(params, 1.0, ext)
    assert widen_at_bound(inside, fit, 'coulomb_friction', QUICK_REFIT_EFFORT) is inside
