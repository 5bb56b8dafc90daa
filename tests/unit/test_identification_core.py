"""Building blocks of the identification: adapter, search, residual statistics, space."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.identification.measurement import Measurement
from valve_model_pkg.identification.model_adapter import prepare_trace, simulate_measurement
from valve_model_pkg.identification.problem import (
    GAP, FitData, baseline_space, effect_space, equivalent_gap_m,
)
from valve_model_pkg.identification.residuals import ljung_box, phase_masks
from valve_model_pkg.identification.search import SearchSettings, direct_search
from valve_model_pkg.identification.sensitivity import noise_std
from valve_model_pkg.model.parameters import ValveParameters
from valve_model_pkg.model import simulate_step


def _step(rate: float = 50e3, duration: float = 0.03, on: float = 1e-3, off: float | None = None,
          volts: float = 24.0) -> Measurement:
    t = np.arange(int(round(duration * rate))) / rate
    v = np.where(t >= on - 1e-12, volts, 0.0)
    if off is not None:
        v = np.where(t >= off - 1e-12, 0.0, v)
    return Measurement(source='step.csv', t_s=t, voltage_v=v, current_a=np.zeros_like(t),
                       supply_pressure_pa=4e5)


@pytest.mark.parametrize('changes', [
    {}, {'eddy_conductance_s': 0.004, 'coulomb_friction_n': 1.0},
    {'leakage_inductance_h': 0.01, 'restitution_coefficient': 0.4},
])
def test_adapter_reproduces_the_models_step_response(changes: dict) -> None:
    p = ValveParameters().replace(**changes)
    m = _step()
    cur, pos = simulate_measurement(p.to_vector()[None, :], prepare_trace(m))
    ref = simulate_step(p, 24.0, duration_s=m.t_s[-1], sample_rate_hz=50e3,
                        step_time_s=1e-3, supply_pressure_pa=4e5)
    n = min(cur.shape[1], ref.coil_current_a.shape[0])
    np.testing.assert_allclose(cur[0, :n], ref.coil_current_a[:n], atol=2e-6)
    np.testing.assert_allclose(pos[0, :n], ref.spool_position_m[:n], atol=1e-9)


def test_adapter_follows_a_pulse_and_samples_off_grid_times() -> None:
    p = ValveParameters()
    m = _step(off=15e-3, duration=0.04)
    cur, pos = simulate_measurement(np.repeat(p.to_vector()[None, :], 3, axis=0),
                                    prepare_trace(m))
    assert np.all(cur[0] == cur[2])
    k_off = np.searchsorted(m.t_s, 15e-3)
    assert cur[0, k_off + 200] < cur[0, k_off]            # decays after switch-off
    assert pos[0, -1] == 0.0 and pos[0].max() == pytest.approx(p.stroke_m)
    # Jittered 1 kHz times (a bag): interpolated from the fine grid.
    rng = np.random.default_rng(0)
    t = np.sort(np.arange(40) * 1e-3 + rng.uniform(0, 2e-5, 40))
    coarse = Measurement(source='bag', t_s=t, voltage_v=np.where(t >= 1e-3, 24.0, 0.0),
                         current_a=np.zeros(40), supply_pressure_pa=4e5)
    c2, _ = simulate_measurement(p.to_vector()[None, :], prepare_trace(coarse))
    assert c2.shape == (1, 40)
    np.testing.assert_allclose(c2[0, 10], np.interp(t[10], m.t_s, cur[0]), atol=5e-3)


def test_l_c_mu_r_and_x_t_act_only_through_the_equivalent_gap() -> None:
    p = ValveParameters()
    s = equivalent_gap_m(p)
    xt = p.total_air_gap_m * 1.1
    q = p.replace(total_air_gap_m=xt, relative_permeability=300.0,
                  core_length_m=300.0 * (s - 2 * xt))
    assert equivalent_gap_m(q) == pytest.approx(s)
    m = _step()
    cur, _ = simulate_measurement(np.array([p.to_vector(), q.to_vector()]), prepare_trace(m))
    np.testing.assert_allclose(cur[0], cur[1], atol=1e-12)
    space = baseline_space(p)
    assert GAP in space.names and 'core_length_m' not in space.names
    back = space.params(space.to_unit(p))
    assert equivalent_gap_m(back) == pytest.approx(s, rel=1e-9)
    assert back.coil_resistance_ohm == pytest.approx(p.coil_resistance_ohm)
    ext = effect_space(space, 'coil_heating')
    assert ext.names[-2:] == ('thermal_resistance_k_per_w', 'thermal_time_constant_s')


def test_cost_is_zero_on_a_noise_free_simulated_measurement() -> None:
    p = ValveParameters()
    m = _step()
    cur, _ = simulate_measurement(p.to_vector()[None, :], prepare_trace(m))
    data = FitData([m.with_current(cur[0])])
    costs = data.cost(np.array([p.to_vector(), p.replace(coil_resistance_ohm=14).to_vector()]))
    assert costs[0] == pytest.approx(0.0, abs=1e-12) and costs[1] > 1e-3
    e = data.errors(p)
    assert e.iae == pytest.approx(0.0, abs=1e-12) and e.nrmse_pct == pytest.approx(0.0)


def test_direct_search_finds_a_box_minimum_and_holds_profile_dims() -> None:
    target = np.array([0.3, 0.7, 0.5, 0.2])

    def fun(u: np.ndarray) -> np.ndarray:
        return np.sum(np.abs(u - target) * [1, 3, 10, 1], axis=1)

    res = direct_search(fun, np.full(4, 0.5), SearchSettings(global_samples=64, starts=3))
    np.testing.assert_allclose(res.u, target, atol=2e-3)
    seen = []

    def spy(u: np.ndarray) -> np.ndarray:
        seen.append(u.copy())
        return fun(u)

    starts = np.array([[0.5, 0.5, 0.5, 0.1], [0.5, 0.5, 0.5, 0.9]])
    direct_search(spy, starts, SearchSettings(global_samples=0, starts=2, restarts=0,
                                              max_iterations=30), fixed=np.array([3]))
    last = np.vstack(seen)[:, 3]
    assert set(np.round(last, 12)) == {0.1, 0.9}


def test_ljung_box_and_noise_estimate() -> None:
    rng = np.random.default_rng(3)
    white = rng.normal(0, 0.01, 4000)
    q, p, rho = ljung_box(white)
    assert p > 0.01 and abs(rho) < 0.05
    ar = np.zeros(4000)
    for k in range(1, 4000):
        ar[k] = 0.8 * ar[k - 1] + white[k]
    assert ljung_box(ar)[1] < 1e-6
    smooth = 0.05 * np.sin(np.linspace(0, 6, 4000))
    assert noise_std(smooth + white) == pytest.approx(0.01, rel=0.1)


def test_phases_follow_the_stroke() -> None:
    p = ValveParameters()
    m = _step(off=15e-3, duration=0.04)
    _, pos = simulate_measurement(p.to_vector()[None, :], prepare_trace(m))
    masks = phase_masks(m, pos[0], p.stroke_m)
    order = [next(name for name, mk in masks.items() if mk[k]) for k in range(m.n_samples)]
    compact = [order[0]] + [b for a, b in zip(order, order[1:]) if a != b]
    assert compact == ['idle', 'before_motion', 'during_motion', 'after_stroke',
                       'steady_state', 'release']
