"""The model's general entry point: simulate_trace_batch under any input trace."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import (
    ElectronicsConfig, InputTrace, ParameterError, ValveParameters, ValveStepper,
    last_period_mean, period_averages, simulate_pwm, simulate_trace_batch,
)

P = ValveParameters()


def test_coil_voltage_trace_is_the_models_step_response() -> None:
    """A bare-coil step as a coil-voltage trace = the step input (a trace applies the edge
    3 ps early, so a sample on it sees the new voltage: 400 A/s x 3 ps = 1.2e-9 A)."""
    rate = 50e3
    t = np.arange(501) / rate
    mat = np.array([P.to_vector(), P.replace(eddy_conductance_s=0.004,
                                             coulomb_friction_n=1.0).to_vector()])
    res = simulate_trace_batch(mat, InputTrace.coil_voltage([0.0, 1e-3], [0.0, 24.0]), t)
    ref = simulate_trace_batch(mat, InputTrace.step(24.0, step_time_s=1e-3), t)
    np.testing.assert_allclose(res.coil_current_a, ref.coil_current_a, rtol=0, atol=1e-8)
    np.testing.assert_allclose(res.spool_position_m, ref.spool_position_m, rtol=0, atol=1e-11)
    assert res.coil_voltage_v[0, 0] == 0.0 and res.coil_voltage_v[0, -1] == 24.0
    assert res.sampling == 'instant' and res.n_steps.shape == (2,)


def test_pwm_command_trace_is_simulate_pwm() -> None:
    """A constant command through the electronics = simulate_pwm at the same samples."""
    ref = simulate_pwm(P, duty=0.4, pwm_frequency_hz=50.0, duration_s=0.05,
                       sample_rate_hz=20e3)
    res = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], 0.4, 50.0, 24.0), ref.t_s)
    np.testing.assert_allclose(res.coil_current_a[0], ref.coil_current_a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.spool_position_m[0], ref.spool_position_m, rtol=0,
                               atol=1e-15)
    np.testing.assert_allclose(res.coil_voltage_v[0], ref.coil_voltage_v, rtol=0, atol=1e-12)


def test_command_changes_follow_the_stepper() -> None:
    """Commands are latched at the next PWM period start, as ValveStepper does."""
    t = np.arange(1, 151) * 1e-3
    st = ValveStepper(P, duty=0.3, pwm_frequency_hz=50.0)
    cur, pos = [], []
    for tk in t:
        st.advance_to(tk)
        if abs(tk - 0.05) < 1e-12:
            st.set_command(0.8, 80.0)  # mid-period (2.5 T): latched at 60 ms
        s = st.sample()
        cur.append(s.coil_current_a)
        pos.append(s.spool_position_m)
    trace = InputTrace.pwm_commands([0.0, t[49]], [0.3, 0.8], [50.0, 80.0], 24.0)
    res = simulate_trace_batch(P, trace, t)
    np.testing.assert_allclose(res.coil_current_a[0], cur, atol=1e-7)
    np.testing.assert_allclose(res.spool_position_m[0], pos, atol=1e-9)


def test_interval_means_are_the_means_over_each_sample_interval() -> None:
    """1 kHz interval means = the mean of a 1 MHz trace over each millisecond."""
    fine = simulate_pwm(P, duty=0.4, pwm_frequency_hz=50.0, duration_s=0.03,
                        sample_rate_hz=1e6)
    t = np.arange(1, 31) * 1e-3
    res = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], 0.4, 50.0), t,
                               sampling='interval_mean')
    assert res.sampling == 'interval_mean'
    for k, tk in enumerate(t):
        sel = (fine.t_s >= tk - 1e-3 - 1e-12) & (fine.t_s <= tk + 1e-12)
        for got, sig, tol in ((res.coil_current_a, fine.coil_current_a, 2e-4),
                              (res.spool_position_m, fine.spool_position_m, 1e-8)):
            mean = np.trapezoid(sig[sel], fine.t_s[sel]) / 1e-3
            assert got[0, k] == pytest.approx(mean, abs=tol)
    inst = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], 0.4, 50.0), t)
    x = np.concatenate(([0.0], inst.spool_position_m[0]))
    np.testing.assert_allclose(res.spool_velocity_m_s[0], np.diff(x) / 1e-3, atol=1e-12)
    np.testing.assert_array_equal(res.coil_temperature_rise_k, inst.coil_temperature_rise_k)


def test_first_sample_at_zero_keeps_its_instant_value() -> None:
    t = np.arange(5) * 1e-3
    res = simulate_trace_batch(P, InputTrace.coil_voltage([0.0], 24.0), t,
                               sampling='interval_mean')
    assert res.coil_voltage_v[0, 0] == 24.0 and res.coil_current_a[0, 0] == 0.0
    assert res.coil_voltage_v[0, 1] == pytest.approx(24.0)


def test_trace_inputs_are_validated() -> None:
    with pytest.raises(ParameterError):
        InputTrace.coil_voltage([0.0, 0.0], [1.0, 2.0])
    with pytest.raises(ParameterError):
        InputTrace.pwm_commands([0.0], 1.5)
    with pytest.raises(ParameterError):
        InputTrace.pwm_commands([0.0], 0.5, 0.0)
    tr = InputTrace.coil_voltage([0.0], 24.0)
    with pytest.raises(ParameterError):
        simulate_trace_batch(P, tr, [0.0, 1e-3], sampling='mean')
    with pytest.raises(ParameterError):
        simulate_trace_batch(P, tr, [1e-3, 0.0])
    with pytest.raises(ParameterError):
        simulate_trace_batch(P, tr, [1e-3], electronics=ElectronicsConfig())


def test_parallel_and_serial_batches_agree() -> None:
    mat = np.repeat(P.to_vector()[None, :], 9, axis=0)
    mat[:, 0] *= np.linspace(0.8, 1.2, 9)
    tr = InputTrace.pwm_commands([0.0, 0.02], [0.5, 0.2], 100.0)
    t = np.arange(1, 41) * 1e-3
    a = simulate_trace_batch(mat, tr, t, parallel=True)
    b = simulate_trace_batch(mat, tr, t, parallel=False)
    np.testing.assert_array_equal(a.coil_current_a, b.coil_current_a)


def test_last_period_mean_is_the_streaming_definition() -> None:
    """last_period_mean (offline) holds the period means and is 0 in the first period."""
    res = simulate_pwm(P, duty=0.4, pwm_frequency_hz=50.0, duration_s=0.07,
                       sample_rate_hz=20e3)
    held = last_period_mean(res.t_s, res.spool_position_m, 0.02)
    ends, means = period_averages(res.t_s, res.spool_position_m, 0.02)
    assert np.all(held[res.t_s < 0.02 - 1e-9] == 0.0)
    assert held[-1] == means[-1]
    # SimulationResult.position_avg_m is the same definition from the kernel's exact means
    np.testing.assert_allclose(res.position_avg_m, held, atol=2e-8)
    assert np.all(res.position_avg_m[res.t_s < 0.02 - 1e-9] == 0.0)
