"""Coulomb friction with stiction on step records is named; a clean record is not.

The records come from the independent truth model (tests/datagen): the paper's valve with
2 N sliding friction and 2.5 N stiction, a 24 V fit step at 4 bar and a 15 V validation
step at 3 bar, 50 kHz, 3 mA noise. Without the effect in the model the baseline misses
the validation step by about 14 mA RMS, close to five times the noise.

The keep rule's bound check is tested on its own (fast): a friction refit leaves the
damping, which the friction force dwarfs on a step, at its search bound, and only a
parameter the data determine may mark a refit a misfit there. Then two identification
runs (``--quick`` effort; slow): the friction record is answered ``coulomb_friction`` with
the validation error cut to the noise, the clean record of the same kind ``none``.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from datagen.cache import step_dataset
from valve_model_pkg.identification import IdentifySettings, identify, read_measurements
from valve_model_pkg.identification.diagnosis import (
    CandidateResult, indistinguishable_runners_up, select,
)
from valve_model_pkg.identification.problem import FitData, baseline_space
from valve_model_pkg.model.parameters import ValveParameters

NOISE_A = 3e-3


@pytest.fixture(scope='module')
def base_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp('stiction')


def _friction_candidate(params: ValveParameters) -> CandidateResult:
    return CandidateResult(effect='coulomb_friction', fields=('coulomb_friction_n',),
                           refitted=True, params=params,
                           parameters={'coulomb_friction_n': params.coulomb_friction_n})


def test_a_refit_at_a_bound_the_data_do_not_see_is_no_misfit(base_dir: Path) -> None:
    truth = step_dataset(base_dir, effect='coulomb_friction_stiction', noise_a=NOISE_A)
    fit = FitData(read_measurements(truth['fit']))
    val = FitData(read_measurements(truth['validate']))
    paper = ValveParameters()
    space = baseline_space(paper)
    lo_delta = space.bounds[space.names.index('spring_pretension_m')].low
    lo_b = space.bounds[space.names.index('damping_n_s_per_m')].low
    # the baseline without friction stands in for it with the pre-tension at its bound
    baseline = paper.replace(spring_pretension_m=lo_delta, damping_n_s_per_m=5.0)
    refit = paper.replace(coulomb_friction_n=2.1, damping_n_s_per_m=lo_b)
    assert fit.at_bound(space, refit) == ['damping_n_s_per_m']
    determined = [n for n in space.names if n != 'damping_n_s_per_m']
    named = select([_friction_candidate(refit)], fit, val, baseline,
                   baseline_at_bound=['spring_pretension_m'], space=space,
                   determined=determined)
    assert named.effect == 'coulomb_friction', named.candidates[0].reason
    # a bound the data do see still marks the refit a misfit
    refused = select([_friction_candidate(refit)], fit, val, baseline,
                     baseline_at_bound=['spring_pretension_m'], space=space,
                     determined=determined + ['damping_n_s_per_m'])
    assert refused.effect == 'none'
    assert 'search bound (damping_n_s_per_m)' in refused.candidates[0].reason


def _judged(effect: str, val_gain: float, dbic_val: float) -> CandidateResult:
    return CandidateResult(effect=effect, fields=(), refitted=True, kept=True,
                           val_gain=val_gain, dbic_val=dbic_val)


def test_a_runner_up_the_hold_out_data_reject_is_told_apart() -> None:
    friction = _judged('coulomb_friction', 0.65, -3481.0)
    # gains close to the winner's (above 80 % of it)
    rejected = _judged('leakage_inductance', 0.54, -497.0)       # 2984 worse on hold-out
    tied = _judged('leakage_inductance', 0.54, -3475.0)          # within 10
    better = _judged('leakage_inductance', 0.54, -3600.0)
    assert indistinguishable_runners_up([friction, rejected]) == []
    assert indistinguishable_runners_up([friction, tied]) == [tied]
    assert indistinguishable_runners_up([friction, better]) == [better]
    # a gain well below the winner's is told apart whatever its criterion
    assert indistinguishable_runners_up([friction, _judged('x', 0.4, -3481.0)]) == []
    # without hold-out data the gain alone decides
    no_val = _judged('leakage_inductance', 0.54, float('nan'))
    assert indistinguishable_runners_up([friction, no_val]) == [no_val]


@pytest.mark.slow
def test_friction_with_stiction_is_named_and_a_clean_record_is_not(base_dir: Path) -> None:
    truth = step_dataset(base_dir, effect='coulomb_friction_stiction', noise_a=NOISE_A)
    ident = identify(truth['fit'], truth['validate'], IdentifySettings(quick=True, seed=1))
    d = ident.diagnosis
    assert d.effect == 'coulomb_friction', [c.to_json() for c in d.candidates]
    base, aug = ident.baseline.validation.rmse, ident.augmented.validation.rmse
    assert base > 3.0 * NOISE_A
    assert aug < 1.2 * NOISE_A and aug < 0.4 * base
    # the sliding force, with the breakaway force folded in, within the truth's pair
    assert 1.5 <= ident.augmented.params.coulomb_friction_n <= 2.75
    clean = step_dataset(base_dir, effect='none', noise_a=NOISE_A)
    none = identify(clean['fit'], clean['validate'], IdentifySettings(quick=True, seed=1))
    assert none.diagnosis.effect == 'none', [c.to_json() for c in none.diagnosis.candidates]
