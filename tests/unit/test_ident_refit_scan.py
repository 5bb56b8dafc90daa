"""The refit's scan (diagnosis.effect_scan) and the slow-effect rule (diagnosis.slow_effect):
an effect with a time constant is scanned jointly in its initial rate and time constant
(coil heating's amount and time constant trade off along a valley of constant R_th / tau
that a scan at the neutral time constant never reaches, and that an axis-aligned grid
steps over), and an effect whose shortest time constant exceeds the search window is
searched on the fit window."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.identification.diagnosis import effect_scan, slow_effect
from valve_model_pkg.identification.problem import baseline_space, effect_space
from valve_model_pkg.model.parameters import EFFECTS, load_parameters

ONE_FIELD = [e for e in EFFECTS if len(EFFECTS[e].fields) == 1]


def _ext(effect: str):
    return effect_space(baseline_space(load_parameters()), effect)


def _origin(ext) -> np.ndarray:
    return np.random.default_rng(0).uniform(0.2, 0.8, ext.size)


def _others_held(ext, effect: str, trial: np.ndarray, origin: np.ndarray) -> bool:
    cols = [ext.names.index(f) for f in EFFECTS[effect].fields]
    others = [j for j in range(ext.size) if j not in cols]
    return np.array_equal(trial[:, others], np.repeat(origin[None, others], len(trial), 0))


@pytest.mark.parametrize('effect', ONE_FIELD)
def test_a_one_field_scan_moves_the_amount_over_its_range(effect: str) -> None:
    ext = _ext(effect)
    origin = _origin(ext)
    trial = effect_scan(ext, effect, origin)
    j = ext.names.index(EFFECTS[effect].fields[0])
    assert len(trial) == 25 and len(np.unique(trial[:, j])) == 25
    assert trial[:, j].min() < 0.03 and trial[:, j].max() > 0.97
    assert _others_held(ext, effect, trial, origin)


def _heating(ext, trial: np.ndarray) -> np.ndarray:
    """(R_th [K/W], tau [s]) of each scan point."""
    return np.array([[ext.params(u).thermal_resistance_k_per_w,
                      ext.params(u).thermal_time_constant_s] for u in trial])


def test_the_heating_scan_covers_rates_and_time_constants_within_bounds() -> None:
    ext = _ext('coil_heating')
    origin = _origin(ext)
    trial = effect_scan(ext, 'coil_heating', origin)
    assert _others_held(ext, 'coil_heating', trial, origin)
    vals = _heating(ext, trial)
    lo, hi = EFFECTS['coil_heating'].bounds['thermal_resistance_k_per_w']
    assert (vals[:, 0] > lo).all() and (vals[:, 0] <= hi * (1 + 1e-9)).all()
    assert vals[:, 1].min() < 2.0 and vals[:, 1].max() > 300.0
    # the loop's coils: 40 K/W at 3 s and at 1.5 s, rates 13 and 27 K/(W s), a scan with
    # tau held at its neutral 60 s reached at most 200/60 = 3.3
    rate = vals[:, 0] / vals[:, 1]
    for r in (13.3, 26.7):
        assert np.min(np.abs(np.log(rate / r))) < np.log(1.6) / 2


@pytest.mark.parametrize('level', [1, 2])
def test_the_zoom_follows_the_valley_of_constant_rate(level: int) -> None:
    ext = _ext('coil_heating')
    origin = ext.to_unit(ext.base)
    coarse = effect_scan(ext, 'coil_heating', origin)
    vals = _heating(ext, coarse)
    near4 = np.abs(np.log(vals[:, 1] / 4.0)) < 0.01   # the grid's tau 3.98 s
    point = coarse[near4][int(np.argmin(np.abs(vals[near4, 0] - 92.0)))]
    r0, t0 = _heating(ext, point[None, :])[0]
    zoom = effect_scan(ext, 'coil_heating', origin, around=point, level=level)
    assert _others_held(ext, 'coil_heating', zoom, origin)
    z = _heating(ext, zoom)
    rate = z[:, 0] / z[:, 1]
    width = np.log(1.7) / 4 ** (level - 1)
    assert np.max(np.abs(np.log(rate / (r0 / t0)))) <= width
    assert len(zoom) > 40   # a 9 x 9 grid, points above the amount's bound dropped
    if level == 1:   # it reaches the time constant of a coil of 40 K/W, 1.5 s from 92, 4
        assert z[:, 1].min() < 1.9 and (z[:, 0][z[:, 1] < 1.9] < 50).any()


def test_only_effects_slower_than_the_window_are_slow() -> None:
    assert slow_effect('coil_heating', 0.4)   # time constant 1 s at the least
    assert not slow_effect('coil_heating', 1.5)
    for effect in EFFECTS:
        if effect != 'coil_heating':
            assert not slow_effect(effect, 0.4), effect
