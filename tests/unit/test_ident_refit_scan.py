"""The refit's scan (diagnosis.effect_scan) and the slow-effect rule (diagnosis.slow_effect):
an effect with two fields is scanned jointly in both (coil heating's amount and time
constant trade off along a valley that a scan at the neutral time constant never reaches),
and an effect whose shortest time constant exceeds the search window is searched on the
fit window."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.identification.diagnosis import effect_scan, slow_effect
from valve_model_pkg.identification.problem import baseline_space, effect_space
from valve_model_pkg.model.parameters import EFFECTS, load_parameters


@pytest.mark.parametrize('effect', list(EFFECTS))
def test_scan_moves_only_the_effects_fields_and_covers_their_range(effect: str) -> None:
    space = baseline_space(load_parameters())
    ext = effect_space(space, effect)
    origin = np.random.default_rng(0).uniform(0.2, 0.8, ext.size)
    trial = effect_scan(ext, effect, origin)
    cols = [ext.names.index(f) for f in EFFECTS[effect].fields]
    others = [j for j in range(ext.size) if j not in cols]
    assert np.array_equal(trial[:, others], np.repeat(origin[None, others], len(trial), 0))
    for j in cols:   # each field spans most of its range
        assert trial[:, j].min() < 0.06 and trial[:, j].max() > 0.94
    # jointly: every amount is tried at every value of the further fields
    n_first = len(np.unique(trial[:, cols[0]]))
    assert len(trial) == n_first * int(np.prod([len(np.unique(trial[:, j]))
                                                for j in cols[1:]]))
    assert len({tuple(r) for r in trial[:, cols]}) == len(trial)


def test_the_heating_scan_reaches_short_time_constants_at_high_amounts() -> None:
    # the loop's record (R_th 40 K/W, tau 3 s) sat in a valley R_th / tau ~ 7 K/(W s); a
    # scan with tau held at its neutral 60 s reached at most 200/60 = 3.3
    ext = effect_space(baseline_space(load_parameters()), 'coil_heating')
    origin = ext.to_unit(ext.base)
    vals = np.array([[ext.params(u).thermal_resistance_k_per_w,
                      ext.params(u).thermal_time_constant_s]
                     for u in effect_scan(ext, 'coil_heating', origin)])
    ratio = vals[:, 0] / vals[:, 1]
    assert ((ratio > 5.0) & (ratio < 10.0)).sum() >= 3
    assert vals[:, 1].min() < 2.0 and vals[:, 1].max() > 300.0


def test_only_effects_slower_than_the_window_are_slow() -> None:
    assert slow_effect('coil_heating', 0.4)   # time constant 1 s at the least
    assert not slow_effect('coil_heating', 1.5)
    for effect in EFFECTS:
        if effect != 'coil_heating':
            assert not slow_effect(effect, 0.4), effect
