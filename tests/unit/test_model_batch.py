"""Batches of the one entry: parallel runs equal single runs; input shapes and validation."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import (
    PARAMETER_FIELDS, ElectronicsConfig, InputTrace, ParameterError, ValveParameters,
    simulate_pwm, simulate_step, simulate_trace_batch,
)

P = ValveParameters()
T_STEP = np.arange(201) * (1 / 20e3)   # the sample grid of simulate_step: 20 kHz, 10 ms


def _pwm(duty: np.ndarray | float, n: int, freq: float = 50.0) -> list[InputTrace]:
    """One constant main PWM command per run."""
    return [InputTrace.pwm_commands([0.0], float(d), freq)
            for d in np.broadcast_to(duty, (n,))]


def test_step_batch_equals_single_runs() -> None:
    rng = np.random.default_rng(1)
    sets = [P.replace(coil_resistance_ohm=float(r), relative_permeability=float(m),
                      coulomb_friction_n=float(f))
            for r, m, f in zip(rng.uniform(11, 15, 6), rng.uniform(100, 140, 6),
                               rng.uniform(0.0, 1.0, 6))]
    volts = np.array([24.0, 15.0, 24.0, 20.0, 24.0, 18.0])
    batch = simulate_trace_batch(np.array([s.to_vector() for s in sets]),
                                 [InputTrace.step(float(v)) for v in volts], T_STEP)
    assert batch.coil_current_a.shape == (6, 201) == batch.spool_position_m.shape
    assert batch.is_batch and batch.n_runs == 6 and batch.n_steps.shape == (6,)
    for k, (s, v) in enumerate(zip(sets, volts)):
        single = simulate_step(s, float(v), 0.01, sample_rate_hz=20e3)
        assert not single.is_batch and single.coil_current_a.shape == (201,)
        # the same kernel arithmetic run by run: equal to the last bit
        np.testing.assert_array_equal(batch.coil_current_a[k], single.coil_current_a)
        np.testing.assert_array_equal(batch.spool_position_m[k], single.spool_position_m)
        assert batch.n_steps[k] == single.n_steps
        one = batch.run(k)
        np.testing.assert_array_equal(one.coil_voltage_v, single.coil_voltage_v)
        assert one.trace.supply_voltage_v[0] == v and one.params == s
    np.testing.assert_array_equal(batch.t_s, single.t_s)


def test_a_late_step_lands_its_edge_on_the_step_time() -> None:
    """A step after t = 0: 0 V before it, the step voltage from the step time on."""
    res = simulate_step(P, 24.0, 0.005, sample_rate_hz=20e3, step_time_s=1e-3)
    before = res.t_s < 1e-3 - 1e-12
    assert np.all(res.coil_voltage_v[before] == 0.0) and np.all(res.coil_current_a[before] == 0)
    assert np.all(res.coil_voltage_v[~before] == 24.0)
    batch = simulate_trace_batch([P, P], InputTrace.step(24.0, 1e-3), res.t_s)
    np.testing.assert_array_equal(batch.coil_current_a[1], res.coil_current_a)


def test_step_batch_accepts_lists_and_broadcasts() -> None:
    batch = simulate_trace_batch(P, [InputTrace.step(24.0), InputTrace.step(15.0)],
                                 T_STEP[:101], supply_pressure_pa=0.0)
    assert batch.coil_current_a.shape[0] == 2
    assert batch.coil_current_a[0, -1] > batch.coil_current_a[1, -1]
    lst = simulate_trace_batch([P, P.replace(coil_resistance_ohm=15.0)], InputTrace.step(),
                               T_STEP[:101])
    assert lst.coil_current_a[0, -1] > lst.coil_current_a[1, -1]
    assert lst.supply_pressure_pa.shape == (2,) and lst.run(1).supply_pressure_pa == 4e5


def test_pwm_batch_equals_period_averages_of_single_runs() -> None:
    duty = np.array([0.0, 0.2, 0.4, 0.7, 1.0])
    res = simulate_trace_batch(P, _pwm(duty, 5), None, electronics=ElectronicsConfig(),
                               n_periods=4)
    assert res.period_avg_position_m.shape == (5, 4) == res.period_end_s.shape
    assert res.t_s.shape == (0,) and res.coil_current_a.shape == (5, 0)
    np.testing.assert_allclose(res.period_end_s[0], [0.02, 0.04, 0.06, 0.08])
    for k, dc in enumerate(duty):
        single = simulate_pwm(P, ElectronicsConfig(), float(dc), 50.0, 0.08,
                              sample_rate_hz=1000.0)
        # the single run also lands on its 1 kHz sample times: other steps, same result
        np.testing.assert_allclose(res.period_avg_position_m[k],
                                   single.period_avg_position_m, rtol=1e-6, atol=1e-15)
    assert res.steady_position_m[0] == 0.0
    assert res.steady_position_m[-1] == pytest.approx(P.stroke_m * (1 - 0.0), rel=1e-9)
    assert np.all(np.diff(res.steady_position_m) >= 0.0)


def test_pwm_batch_pressure_shifts_the_map_down() -> None:
    # Section 5 / Fig. 8: a higher supply pressure lowers the average position
    res = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], 0.3, 50.0), None,
                               supply_pressure_pa=np.array([3e5, 4e5, 5e5, 6e5]),
                               n_periods=3)
    assert np.all(np.diff(res.steady_position_m) < 0.0)


def test_period_means_with_samples_are_those_of_simulate_pwm() -> None:
    """n_periods with a uniform grid: the runs of a batch equal simulate_pwm's."""
    single = simulate_pwm(P, None, 0.4, 100.0, 0.035, sample_rate_hz=2000.0)
    batch = simulate_trace_batch([P, P.replace(coil_resistance_ohm=14.0)],
                                 InputTrace.pwm_commands([0.0], 0.4, 100.0), single.t_s,
                                 n_periods=10)
    assert batch.period_end_s.shape == (2, 3)        # 3 of at most 10 periods completed
    np.testing.assert_array_equal(batch.period_avg_position_m[0],
                                  single.period_avg_position_m)
    np.testing.assert_array_equal(batch.run(0).position_avg_m, single.position_avg_m)
    np.testing.assert_array_equal(batch.position_avg_m[0], single.position_avg_m)
    np.testing.assert_array_equal(batch.mass_flow_kg_s[0], single.mass_flow_kg_s)
    assert single.position_avg_m[-1] == single.period_avg_position_m[-1] > 0.0


def test_per_run_frequencies_pad_the_periods_with_nan() -> None:
    res = simulate_trace_batch(P, [InputTrace.pwm_commands([0.0], 0.5, f)
                                   for f in (50.0, 100.0)], np.arange(51) * 1e-3,
                               n_periods=8)
    assert res.period_end_s.shape == (2, 5)
    assert np.all(np.isnan(res.period_end_s[0, 2:])) and np.all(np.isfinite(res.period_end_s[1]))
    assert res.run(0).period_end_s.tolist() == [0.02, 0.04]
    assert res.steady_position_m[0] == res.period_avg_position_m[0, 1]


def test_batch_validation() -> None:
    bad = np.tile(P.to_vector(), (3, 1))
    bad[1, PARAMETER_FIELDS.index('spool_mass_kg')] = -1.0
    step = InputTrace.step()
    with pytest.raises(ParameterError, match=r'parameter row 1: spool_mass_kg must be '
                                             r'positive, got -1\.0'):
        simulate_trace_batch(bad, step, T_STEP)
    with pytest.raises(ParameterError, match='columns'):
        simulate_trace_batch(np.zeros((2, 3)), step, T_STEP)
    with pytest.raises(ParameterError, match='2 traces given for 3 runs'):
        simulate_trace_batch(np.tile(P.to_vector(), (3, 1)), [step, step], T_STEP)
    with pytest.raises(ParameterError, match=r'duty must be in \[0, 1\]'):
        InputTrace.pwm_commands([0.0], 1.2)
    pwm = InputTrace.pwm_commands([0.0], 0.5)
    with pytest.raises(ParameterError, match='n_periods must be at least 1'):
        simulate_trace_batch(P, pwm, None, n_periods=0)
    with pytest.raises(ParameterError, match='need main PWM commands'):
        simulate_trace_batch(P, step, T_STEP, n_periods=2)
    with pytest.raises(ParameterError, match='uniform grid'):
        simulate_trace_batch(P, pwm, [0.001, 0.002, 0.004], n_periods=2)
    with pytest.raises(ParameterError, match='constant input'):
        simulate_trace_batch(P, InputTrace.pwm_commands([0.0, 0.01], [0.5, 0.2]), T_STEP,
                             n_periods=2)
    with pytest.raises(ParameterError, match='give sample_times_s'):
        simulate_trace_batch(P, pwm)
    with pytest.raises(ParameterError, match='one kind'):
        simulate_trace_batch([P, P], [pwm, step], T_STEP)
    with pytest.raises(ParameterError, match='needs its period means'):
        simulate_trace_batch(P, pwm, T_STEP).position_avg_m
