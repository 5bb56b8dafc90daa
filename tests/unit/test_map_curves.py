"""Curve features (dead band, saturation, width) and periodic-steady-state detection."""
from __future__ import annotations

import math

import numpy as np
import pytest

from valve_model_pkg.maps import (SteadyStateCriterion, curve_features, detect_steady_state,
                                  monotone_envelope)
from valve_model_pkg.maps.steady_state import steady_at

DUTY = np.round(np.linspace(0.0, 1.0, 101), 12)


@pytest.mark.parametrize('start, end, dead_band, opening, saturation', [
    (0.10, 0.80, 0.10, 0.11, 0.80),     # ramp exactly on grid points
    (0.105, 0.795, 0.10, 0.11, 0.80),   # between grid points: the grid brackets the edges
    (0.0, 0.5, 0.0, 0.01, 0.50),
])
def test_dead_band_and_saturation(start: float, end: float, dead_band: float, opening: float,
                                  saturation: float) -> None:
    x = np.clip((DUTY - start) / (end - start), 0.0, 1.0)
    f = curve_features(DUTY, x)
    assert f.dead_band_duty == pytest.approx(dead_band)
    assert f.opening_duty == pytest.approx(opening)
    assert f.saturation_duty == pytest.approx(saturation)
    assert f.effective_width == pytest.approx(saturation - dead_band)
    assert f.max_decrease == 0.0 and f.opens


def test_valve_that_never_opens_or_never_saturates() -> None:
    closed = curve_features(DUTY, np.zeros_like(DUTY))
    assert closed.dead_band_duty == 1.0 and math.isnan(closed.opening_duty)
    assert not closed.opens and math.isnan(closed.effective_width)
    partial = curve_features(DUTY, 0.5 * DUTY)
    assert math.isnan(partial.saturation_duty) and partial.dead_band_duty == 0.0


def test_dip_is_measured_and_envelope_is_monotone() -> None:
    x = np.clip((DUTY - 0.1) / 0.7, 0.0, 1.0)
    x[30] -= 0.05
    f = curve_features(DUTY, x)
    assert f.max_decrease == pytest.approx(x[29] - x[30])
    env = monotone_envelope(x)
    assert np.all(np.diff(env) >= 0.0) and env[30] == pytest.approx(x[29])
    assert curve_features(DUTY, x).as_dict()['dead_band_duty'] == pytest.approx(0.1)


def test_features_refuse_bad_shapes() -> None:
    with pytest.raises(ValueError, match='equal 1-D arrays'):
        curve_features(DUTY, DUTY[:-1])


# --- periodic steady state --------------------------------------------------------------
CRIT = SteadyStateCriterion(tolerance=1e-4, window=3, min_periods=4, max_periods=400,
                            max_cycle=16)


def test_geometric_convergence_settles_when_changes_and_drift_are_small() -> None:
    a = 0.5 - 0.3 * 0.3 ** np.arange(30)
    (s,) = detect_steady_state(a[None, :], CRIT)
    assert s.converged and s.cycle == 1
    assert abs(s.value - 0.5) <= CRIT.tolerance
    # the first period whose last three changes are within tolerance (0.3^k * 0.21 ...)
    changes = np.abs(np.diff(a))
    k = s.periods - 1
    assert np.all(changes[k - 3:k] <= CRIT.tolerance)


def test_slow_creep_is_not_taken_for_steady() -> None:
    """Changes of 5e-5 per period are below the tolerance, but the drift is not."""
    a = 0.2 + 5e-5 * np.arange(40)
    (s,) = detect_steady_state(a[None, :], CRIT)
    assert s is None
    (final,) = detect_steady_state(a[None, :], CRIT, final=True)
    assert not final.converged and final.value == pytest.approx(np.mean(a[20:]))


@pytest.mark.parametrize('cycle', [2, 3, 8])
def test_subharmonic_cycles_are_periodic_steady_states(cycle: int) -> None:
    pattern = 0.45 + 0.01 * np.sin(2 * np.pi * np.arange(cycle) / cycle + 0.3)
    a = np.concatenate([np.linspace(0.0, 0.4, 5), np.tile(pattern, 12)])
    (s,) = detect_steady_state(a[None, :], CRIT)
    assert s.converged and s.cycle == cycle
    assert s.value == pytest.approx(pattern.mean(), abs=1e-12)


def test_first_periods_are_never_taken() -> None:
    a = np.full(10, 0.3)
    (s,) = detect_steady_state(a[None, :], CRIT)
    assert s.periods == CRIT.min_periods


def test_streaming_detection_equals_offline() -> None:
    """steady_at after every period (what the generator does) = detect on the whole run."""
    a = np.concatenate([0.5 - 0.3 * 0.4 ** np.arange(12), np.tile([0.51, 0.49], 10)])
    (offline,) = detect_steady_state(a[None, :], CRIT)
    first = next(s for k in range(a.size) if (s := steady_at(a[:k + 1], k, CRIT)))
    assert first == offline


def test_criterion_validation_and_round_trip() -> None:
    assert SteadyStateCriterion.from_dict(CRIT.as_dict()) == CRIT
    with pytest.raises(ValueError, match='tolerance must be positive'):
        SteadyStateCriterion(tolerance=0.0)
    assert 'tolerance' in CRIT.as_dict()['method']
