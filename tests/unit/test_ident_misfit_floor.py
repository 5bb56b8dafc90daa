"""Intervals that widen when the residual is structured: a model error is
a bias, so no parameter is pinned tighter than the change that moves the current by the
residual's structure; white noise alone leaves the intervals as they were."""
from __future__ import annotations

import numpy as np

from valve_model_pkg.identification.sensitivity import misfit_floor_pct


def _problem(n: int = 2000):
    t = np.linspace(0.0, 1.0, n)
    # Two parameters: a level and a slope of the current [A per unit relative change].
    jac = np.column_stack([np.full(n, 0.5), 0.5 * t])
    return t, jac


def _white_var(jac: np.ndarray, sigma: float) -> np.ndarray:
    return np.diag(np.linalg.inv(jac.T @ jac / sigma ** 2))


def test_noise_alone_sets_no_floor() -> None:
    t, jac = _problem()
    sigma = 3e-3
    floors = []
    for seed in range(20):
        r = np.random.default_rng(seed).normal(0.0, sigma, t.size)
        floor, r_s = misfit_floor_pct(jac, [r], sigma, _white_var(jac, sigma))
        floors.append(r_s)
    # The noise's own spread is not structure (at most a rare, tiny excess).
    assert sum(f > 0.0 for f in floors) <= 1


def test_structure_widens_to_the_bias_it_can_hide() -> None:
    t, jac = _problem()
    sigma = 1e-3
    r = 5e-3 * np.sin(2 * np.pi * 3 * t) + np.random.default_rng(1).normal(0, sigma, t.size)
    var = _white_var(jac, sigma)
    floor, r_s = misfit_floor_pct(jac, [r], sigma, var)
    assert abs(r_s - 5e-3 / np.sqrt(2)) < 0.4e-3
    white_ci = 1.96 * 100 * np.sqrt(var)
    assert np.all(floor > 10 * white_ci)
    # The level parameter: a 1 % change moves the current by 5 mA; 3.5 mA of structure
    # (with the slope free to compensate) hides about 1.4 % -- the floor says so.
    assert 1.5 < floor[0] < 5.0
