"""Integration kernel: convergence, event location against analytic cases, the effects."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from valve_model_pkg.model import (
    ElectronicsConfig, ValveParameters, simulate_pwm, simulate_step, step_metrics,
)
from valve_model_pkg.model import kernel as K
from valve_model_pkg.model.magnetics import MU_0, inductance, magnetic_force
from valve_model_pkg.model.mechanics import MODE_CLOSED, MODE_FREE, MODE_STUCK

P = ValveParameters()
L0 = float(inductance(P, 0.0))
BLOCKED_PA = 3.0e7  # a supply pressure the magnet cannot overcome: the spool stays closed


# --- convergence ----------------------------------------------------------------------
@pytest.mark.parametrize('experiment', ['step24', 'step15', 'pwm'])
def test_halving_the_step_changes_current_by_less_than_0_1_percent(experiment: str) -> None:
    def run(scale: float):
        kw = dict(h_free_s=K.DEFAULT_H_FREE_S * scale, h_stop_s=K.DEFAULT_H_STOP_S * scale,
                  sample_rate_hz=2000.0)
        if experiment == 'pwm':
            return simulate_pwm(P, ElectronicsConfig(), 0.4, 50.0, 0.1, **kw)
        return simulate_step(P, 24.0 if experiment == 'step24' else 15.0, 0.02, **kw)

    full, half, fine = run(1.0), run(0.5), run(1 / 16)
    peak = np.abs(fine.coil_current_a).max()
    assert np.abs(full.coil_current_a - half.coil_current_a).max() < 1e-3 * peak
    assert np.abs(full.coil_current_a - fine.coil_current_a).max() < 1e-3 * peak
    assert np.abs(full.spool_position_m - fine.spool_position_m).max() < 1e-3 * P.stroke_m
    # in fact far better: document-level margin
    assert np.abs(full.coil_current_a - fine.coil_current_a).max() < 1e-5 * peak


def test_step_response_matches_solve_ivp_reference() -> None:
    """Independent reference: scipy with events for leaving the stop and the impact."""
    v, p_sup = 24.0, 4.0e5
    f_prs = (P.area_a1_m2 - P.area_a2_m2) * p_sup
    kl = P.coil_turns ** 2 * P.core_area_m2 * P.relative_permeability * MU_0

    def ind(x: float) -> float:
        return kl / (P.core_length_m + 2 * P.relative_permeability * (P.total_air_gap_m - x))

    def held(t, s):
        return [(v - P.coil_resistance_ohm * s[0]) / ind(0.0), 0.0, 0.0]

    def free(t, s):
        i, x, xd = s
        lx = ind(x)
        fm = lx ** 2 * i ** 2 / (P.coil_turns ** 2 * P.core_area_m2 * MU_0)
        di = (v - P.coil_resistance_ohm * i) / lx - 2 * P.relative_permeability * lx * xd \
            * i / kl
        return [di, xd, (fm - P.damping_n_s_per_m * xd - P.spring_stiffness_n_per_m * (
            x + P.spring_pretension_m) + f_prs) / P.spool_mass_kg]

    def leave(t, s):
        return float(magnetic_force(P, s[0], 0.0)) - P.spring_stiffness_n_per_m \
            * P.spring_pretension_m + f_prs
    leave.terminal = True
    leave.direction = 1

    def hit(t, s):
        return s[1] - P.stroke_m
    hit.terminal = True
    hit.direction = 1

    tol = dict(rtol=1e-10, atol=1e-12, method='DOP853')
    a = solve_ivp(held, (0, 0.02), [0, 0, 0], events=leave, dense_output=True, **tol)
    t1 = a.t_events[0][0]
    b = solve_ivp(free, (t1, 0.02), a.y_events[0][0], events=hit, dense_output=True, **tol)
    t2 = b.t_events[0][0]
    c = solve_ivp(lambda t, s: [(v - P.coil_resistance_ohm * s[0]) / ind(P.stroke_m), 0, 0],
                  (t2, 0.02), [b.y_events[0][0][0], P.stroke_m, 0.0], dense_output=True,
                  **tol)
    res = simulate_step(P, v, 0.02, p_sup, sample_rate_hz=20e3)
    ref = np.array([(a if t < t1 else b if t < t2 else c).sol(t)[0] for t in res.t_s])
    np.testing.assert_allclose(res.coil_current_a, ref, atol=1e-5 * ref.max())
    m = step_metrics(simulate_step(P, v, 0.006, p_sup, sample_rate_hz=1e6))
    assert m.motion_start_s == pytest.approx(t1, abs=1.01e-6)
    assert m.stroke_end_s == pytest.approx(t2, abs=1.01e-6)


# --- events against analytic cases -----------------------------------------------------
def _kernel_run(params: ValveParameters, y0: list[float], mode: int, t_end: float,
                dt: float = 1e-6, supply_pa: float = 0.0, volts: float = 0.0):
    p = K.derive_parameters(params.to_vector())
    e = ElectronicsConfig.off().to_vector()
    duty = 1.0 if volts != 0.0 else 0.0
    d = K.new_drive_state(volts, duty, 1e9, 0.0, supply_pa, 0.0, sample_dt_s=dt)
    d[K.D_MODE] = mode
    y = np.array(y0 + [0.0, 0.0], dtype=float)[:K.N_Y]
    n = int(round(t_end / dt)) + 1
    out = np.zeros((n, K.N_OUT))
    K.advance(p, e, y, d, (n - 1) * dt, out=out)
    return np.arange(n) * dt, out


def test_motion_start_matches_rl_threshold() -> None:
    p_sup = 4.0e5
    f_needed = P.spring_stiffness_n_per_m * P.spring_pretension_m - (
        P.area_a1_m2 - P.area_a2_m2) * p_sup
    i_star = math.sqrt(f_needed / float(magnetic_force(P, 1.0, 0.0)))
    t_star = -L0 / 13.0 * math.log(1 - i_star * 13.0 / 24.0)
    t, out = _kernel_run(P, [0.0, 0.0, 0.0], MODE_CLOSED, 0.003, supply_pa=p_sup, volts=24.0)
    t_leave = t[np.argmax(out[:, K.O_MODE] == MODE_FREE)]
    assert t_leave == pytest.approx(t_star, abs=1.01e-6)
    held = t < t_star - 1e-6
    np.testing.assert_allclose(out[held, K.O_I], 24 / 13 * (1 - np.exp(-t[held] * 13 / L0)),
                               rtol=1e-9, atol=1e-12)


def test_free_fall_impact_time_and_plastic_stop() -> None:
    params = P.replace(damping_n_s_per_m=0.0)
    omega = math.sqrt(params.spring_stiffness_n_per_m / params.spool_mass_kg)
    x0, delta = params.stroke_m, params.spring_pretension_m
    t_hit = math.acos(delta / (x0 + delta)) / omega
    t, out = _kernel_run(params, [0.0, x0, 0.0], MODE_FREE, 0.003)
    x = out[:, K.O_X]
    np.testing.assert_allclose(x[t < t_hit], -delta + (x0 + delta) * np.cos(
        omega * t[t < t_hit]), atol=1e-11)
    k = int(np.argmax(x <= 0.0))
    assert t[k] == pytest.approx(t_hit, abs=1.01e-6)
    assert np.all(x >= 0.0) and np.all(x[k:] == 0.0)
    assert np.all(out[k:, K.O_MODE] == MODE_CLOSED)
    assert np.all(out[k:, K.O_XDOT] == 0.0)


def test_bounce_height_follows_restitution() -> None:
    e_r = 0.5
    params = P.replace(damping_n_s_per_m=0.0, restitution_coefficient=e_r)
    omega = math.sqrt(params.spring_stiffness_n_per_m / params.spool_mass_kg)
    x0, delta = params.stroke_m, params.spring_pretension_m
    v_imp = omega * math.sqrt((x0 + delta) ** 2 - delta ** 2)
    apex = math.sqrt(delta ** 2 + (e_r * v_imp / omega) ** 2) - delta
    t, out = _kernel_run(params, [0.0, x0, 0.0], MODE_FREE, 0.004, dt=2e-7)
    x = out[:, K.O_X]
    t_hit = math.acos(delta / (x0 + delta)) / omega
    k = int(np.argmax(t > t_hit))  # the impact falls between samples
    assert x[k - 1] > x[k] < x[k + 1]
    assert x[k:].max() == pytest.approx(apex, rel=1e-4)
    # it settles on the stop after a finite number of bounces
    assert out[-1, K.O_MODE] == MODE_CLOSED and x[-1] == 0.0
    assert np.all(x >= 0.0) and np.all(x <= params.stroke_m)


def test_bounce_at_open_stop_in_a_step_response() -> None:
    bouncy = simulate_step(P.replace(restitution_coefficient=0.6), 24.0, 0.01,
                           sample_rate_hz=1e6)
    x = bouncy.spool_position_m
    k = int(np.argmax(x >= 0.99 * P.stroke_m))
    assert x[k:].min() < P.stroke_m * 0.9     # bounces off the stop
    assert x[-1] == P.stroke_m                # and settles there
    assert x.max() <= P.stroke_m


def test_coulomb_friction_delays_motion_by_the_analytic_amount() -> None:
    fc = 1.0
    params = P.replace(coulomb_friction_n=fc)
    f_needed = P.spring_stiffness_n_per_m * P.spring_pretension_m + fc - (
        P.area_a1_m2 - P.area_a2_m2) * 4e5
    i_star = math.sqrt(f_needed / float(magnetic_force(P, 1.0, 0.0)))
    t_star = -L0 / 13.0 * math.log(1 - i_star * 13.0 / 24.0)
    t, out = _kernel_run(params, [0.0, 0.0, 0.0], MODE_CLOSED, 0.003, supply_pa=4e5,
                         volts=24.0)
    assert t[np.argmax(out[:, K.O_MODE] == MODE_FREE)] == pytest.approx(t_star, abs=1.01e-6)


def test_stiction_holds_the_spool_mid_stroke() -> None:
    # spring force at x = 0.15 mm is k (x + delta) = 12.5 N < F_c: launched upwards, the
    # spool stops and stays stuck
    params = P.replace(coulomb_friction_n=13.0, damping_n_s_per_m=0.0)
    t, out = _kernel_run(params, [0.0, 0.15e-3, 0.2], MODE_FREE, 0.002)
    x, v, mode = out[:, K.O_X], out[:, K.O_XDOT], out[:, K.O_MODE]
    k = int(np.argmax(mode == MODE_STUCK))
    assert k > 0
    assert np.all(mode[k:] == MODE_STUCK) and np.all(v[k:] == 0.0)
    assert np.ptp(x[k:]) == 0.0
    # constant deceleration (F_c + spring) / m, approximately: v^2 / (2 a) travel
    a = (13.0 + params.spring_stiffness_n_per_m * (0.15e-3 + params.spring_pretension_m)) \
        / params.spool_mass_kg
    assert x[k] - 0.15e-3 == pytest.approx(0.2 ** 2 / (2 * a), rel=0.02)
    # a weaker friction cannot hold it: it comes back to the closed stop
    weak = P.replace(coulomb_friction_n=5.0)
    _, out = _kernel_run(weak, [0.0, 0.15e-3, 0.2], MODE_FREE, 0.004)
    assert out[-1, K.O_MODE] == MODE_CLOSED


# --- electrical effects at a blocked spool (analytic) -----------------------------------
def test_leakage_inductance_slows_the_rl_rise() -> None:
    leak = 0.02
    res = simulate_step(P.replace(leakage_inductance_h=leak), 24.0, 0.01, BLOCKED_PA,
                        sample_rate_hz=10e3)
    assert np.all(res.spool_position_m == 0.0)
    np.testing.assert_allclose(res.coil_current_a, 24 / 13 * (1 - np.exp(-res.t_s * 13 / (
        L0 + leak))), rtol=1e-8, atol=1e-12)


def test_eddy_conductance_shunts_the_inductance() -> None:
    g = 0.01
    res = simulate_step(P.replace(eddy_conductance_s=g), 24.0, 0.01, BLOCKED_PA,
                        sample_rate_hz=10e3, step_time_s=1e-4)
    t = res.t_s - 1e-4
    on = t >= 0
    tau = L0 * (1 + 13 * g) / 13
    i_m = 24 / 13 * (1 - np.exp(-t[on] / tau))
    v_branch = (24 - 13 * i_m) / (1 + 13 * g)
    np.testing.assert_allclose(res.coil_current_a[on], i_m + g * v_branch, rtol=1e-8)
    # the terminal current jumps at the step: the resistor has no inductance
    assert res.coil_current_a[on][0] == pytest.approx(g * 24 / (1 + 13 * g))
    assert np.all(res.coil_current_a[~on] == 0.0)


def test_saturation_speeds_up_the_current_rise() -> None:
    beta = 0.8
    res = simulate_step(P.replace(saturation_coefficient_per_a=beta), 24.0, 0.01, BLOCKED_PA,
                        sample_rate_hz=100e3)
    # t(i) = int_0^i L0 / ((1 + beta j)^2 (V - R j)) dj
    for i_q in (0.5, 1.0, 1.5):
        t_q = quad(lambda j: L0 / ((1 + beta * j) ** 2 * (24 - 13 * j)), 0, i_q)[0]
        assert np.interp(i_q, res.coil_current_a, res.t_s) == pytest.approx(t_q, rel=1e-5)
    plain = simulate_step(P, 24.0, 0.01, BLOCKED_PA, sample_rate_hz=100e3)
    assert np.all(res.coil_current_a[1:] > plain.coil_current_a[1:])


def test_coil_heating_reaches_the_thermal_fixed_point() -> None:
    r_th, tau = 20.0, 0.02
    hot = P.replace(thermal_resistance_k_per_w=r_th, thermal_time_constant_s=tau)
    res = simulate_step(hot, 24.0, 0.3, BLOCKED_PA, sample_rate_hz=1000.0)
    # fixed point: dT = R_th V^2 / R(dT), R = R0 (1 + alpha dT)
    d_t = 10.0
    for _ in range(200):
        d_t = r_th * 24.0 ** 2 / (13.0 * (1 + 0.00393 * d_t))
    assert res.coil_temperature_rise_k[-1] == pytest.approx(d_t, rel=1e-3)
    assert res.coil_current_a[-1] == pytest.approx(24 / (13 * (1 + 0.00393 * d_t)), rel=1e-3)
    cold = simulate_step(P.replace(thermal_time_constant_s=5.0), 24.0, 0.02)
    base = simulate_step(P, 24.0, 0.02)
    np.testing.assert_array_equal(cold.coil_current_a, base.coil_current_a)  # R_th = 0: neutral


def test_reverse_current_is_blocked_by_the_driver() -> None:
    strong = ElectronicsConfig(capacitor_voltage_v=200.0, capacitor_discharge_time_s=5e-3)
    res = simulate_pwm(P, strong, 0.4, 50.0, 0.04, sample_rate_hz=50e3)
    assert res.coil_current_a.min() == 0.0
    free = simulate_pwm(P, strong.replace(block_reverse_current=False), 0.4, 50.0, 0.04,
                        sample_rate_hz=50e3)
    assert free.coil_current_a.min() < -0.01


def test_electronics_off_is_the_bare_coil() -> None:
    res = simulate_pwm(P, ElectronicsConfig.off(), 0.4, 50.0, 0.04, sample_rate_hz=10e3)
    high = (res.t_s % 0.02) < 0.008
    assert np.all(res.coil_voltage_v[high] == 24.0)
    assert np.all(res.coil_voltage_v[~high] == 0.0)


def test_a_timer_peak_phase_applies_the_supply_for_its_time() -> None:
    cfg = ElectronicsConfig(peak_end='timer', max_boost_time_s=5e-3)
    res = simulate_pwm(P, cfg, 0.4, 50.0, 0.02, sample_rate_hz=100e3)
    boost = (res.t_s < 5e-3 - 1e-9)
    assert np.all(res.coil_voltage_v[boost] == 24.0)
    assert np.any(res.coil_voltage_v[(res.t_s > 5e-3) & (res.t_s < 8e-3)] == 0.0)


@pytest.mark.parametrize('bad', ['float32', 'strided'])
def test_a_state_the_kernel_cannot_write_into_is_refused(bad: str) -> None:
    """The kernel updates y and d in place: a copy would lose the update, so it refuses."""
    p = K.derive_parameters(P.to_vector())
    e = ElectronicsConfig().to_vector()
    d = K.new_drive_state(24.0, 0.5, 0.02, 0.0, 4e5)
    y = np.zeros(K.N_Y, dtype=np.float32) if bad == 'float32' else np.zeros(2 * K.N_Y)[::2]
    with pytest.raises(TypeError, match='y must be a writeable C-contiguous float64'):
        K.advance(p, e, y, d, 1e-3)
    assert d[K.D_T] == 0.0  # nothing ran


def test_inputs_of_any_float_layout_are_taken() -> None:
    """Read-only inputs (parameters, electronics) may be lists or other dtypes."""
    p = K.derive_parameters(list(P.to_vector()))
    e = ElectronicsConfig().to_vector()
    y = np.zeros(K.N_Y)
    d = K.new_drive_state(24, 1, 1.0)
    K.advance(p, list(e), y, d, 0.01)
    assert d[K.D_T] == pytest.approx(0.01) and y[K.Y_X] > 0.0


def test_model_core_is_ros_free() -> None:
    root = Path(__file__).resolve().parents[2] / 'valve_model_pkg'
    code = ('import sys; sys.path.insert(0, %r); import valve_model_pkg.model, '
            'valve_model_pkg.cli.simulate; print("rclpy" in sys.modules)' % str(root))
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == 'False'
    for path in (root / 'valve_model_pkg' / 'model').glob('*.py'):
        assert 'rclpy' not in path.read_text(), path
