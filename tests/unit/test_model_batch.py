"""Batch API: parallel runs equal single runs; input shapes and validation."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import (
    PARAMETER_FIELDS, ElectronicsConfig, ParameterError, ValveParameters, simulate_pwm,
    simulate_pwm_batch, simulate_step, simulate_step_batch,
)

P = ValveParameters()


def test_step_batch_equals_single_runs() -> None:
    rng = np.random.default_rng(1)
    sets = [P.replace(coil_resistance_ohm=float(r), relative_permeability=float(m),
                      coulomb_friction_n=float(f))
            for r, m, f in zip(rng.uniform(11, 15, 6), rng.uniform(100, 140, 6),
                               rng.uniform(0.0, 1.0, 6))]
    volts = np.array([24.0, 15.0, 24.0, 20.0, 24.0, 18.0])
    batch = simulate_step_batch(np.array([s.to_vector() for s in sets]), volts, 0.01,
                                sample_rate_hz=20e3)
    assert batch.current_a.shape == (6, 201) == batch.position_m.shape
    for k, (s, v) in enumerate(zip(sets, volts)):
        single = simulate_step(s, float(v), 0.01, sample_rate_hz=20e3)
        np.testing.assert_allclose(batch.current_a[k], single.current_a, rtol=0, atol=1e-12)
        np.testing.assert_allclose(batch.position_m[k], single.position_m, atol=1e-15)
    np.testing.assert_allclose(batch.t_s, single.t_s)


def test_step_batch_accepts_lists_and_broadcasts() -> None:
    batch = simulate_step_batch(P, np.array([24.0, 15.0]), 0.005, supply_pressure_pa=0.0)
    assert batch.current_a.shape[0] == 2
    assert batch.current_a[0, -1] > batch.current_a[1, -1]
    lst = simulate_step_batch([P, P.replace(coil_resistance_ohm=15.0)], 24.0, 0.005)
    assert lst.current_a[0, -1] > lst.current_a[1, -1]


def test_pwm_batch_equals_period_averages_of_single_runs() -> None:
    duty = np.array([0.0, 0.2, 0.4, 0.7, 1.0])
    res = simulate_pwm_batch(P, ElectronicsConfig(), duty, 50.0, 4e5, n_periods=4)
    assert res.position_avg_m.shape == (5, 4)
    for k, dc in enumerate(duty):
        single = simulate_pwm(P, ElectronicsConfig(), float(dc), 50.0, 0.08,
                              sample_rate_hz=1000.0)
        # the single run also lands on its 1 kHz sample times: other steps, same result
        np.testing.assert_allclose(res.position_avg_m[k], single.period_avg_position_m,
                                   rtol=1e-6, atol=1e-15)
    assert res.steady_position_m[0] == 0.0
    assert res.steady_position_m[-1] == pytest.approx(P.stroke_m * (1 - 0.0), rel=1e-9)
    assert np.all(np.diff(res.steady_position_m) >= 0.0)


def test_pwm_batch_pressure_shifts_the_map_down() -> None:
    # Section 5 / Fig. 8: a higher supply pressure lowers the average position
    res = simulate_pwm_batch(P, None, 0.3, 50.0, np.array([3e5, 4e5, 5e5, 6e5]),
                             n_periods=3)
    assert np.all(np.diff(res.steady_position_m) < 0.0)


def test_batch_validation() -> None:
    bad = np.tile(P.to_vector(), (3, 1))
    bad[1, PARAMETER_FIELDS.index('spool_mass_kg')] = -1.0
    with pytest.raises(ParameterError, match=r'parameter row 1: spool_mass_kg must be '
                                             r'positive, got -1\.0'):
        simulate_step_batch(bad)
    with pytest.raises(ParameterError, match='columns'):
        simulate_step_batch(np.zeros((2, 3)))
    with pytest.raises(ParameterError, match=r'voltage_v must be a scalar or have shape'):
        simulate_step_batch(np.tile(P.to_vector(), (3, 1)), np.ones(2))
    with pytest.raises(ParameterError, match=r'duty must be in \[0, 1\]'):
        simulate_pwm_batch(P, duty=np.array([0.5, 1.2]))
    with pytest.raises(ParameterError, match='n_periods must be at least 1'):
        simulate_pwm_batch(P, n_periods=0)
