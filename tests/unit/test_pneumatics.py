"""The cylinder plant (C1-C6) and the flow-commanding position controller."""
from __future__ import annotations

import math

import numpy as np
import pytest

from valve_model_pkg.model.orifice import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.pneumatics.controller import ControllerGains, PositionController
from valve_model_pkg.pneumatics.cylinder import Cylinder, CylinderParameters, CylinderState


def test_static_equilibrium_holds_the_piston_still() -> None:
    par = CylinderParameters(bleed_discharge_area_m2=0.0, coulomb_friction_n=0.0)
    y = 0.05
    cyl = Cylinder(par, CylinderState(par.equilibrium_pressure_pa(y), y, 0.0))
    cyl.step(0.5, 0.0)
    assert cyl.state.position_m == pytest.approx(y, abs=1e-9)
    assert cyl.state.velocity_m_s == pytest.approx(0.0, abs=1e-9)


def test_closed_chamber_mass_balance_matches_the_gas_law() -> None:
    """No bleed, piston at its stop: p V = m R T after a known mass went in (isothermal n=1)."""
    par = CylinderParameters(bleed_discharge_area_m2=0.0, polytropic_exponent=1.0,
                             spring_preload_n=1e4)  # preload keeps the piston at y = 0
    cyl = Cylinder(par)
    flow, dt = 1e-4, 0.2
    cyl.step(dt, flow)
    m0 = ATMOSPHERIC_PRESSURE_PA * par.dead_volume_m3 / (
        par.gas_constant_j_per_kg_k * par.temperature_k)
    expected = (m0 + flow * dt) * par.gas_constant_j_per_kg_k * par.temperature_k \
        / par.dead_volume_m3
    assert cyl.state.position_m == 0.0
    np.testing.assert_allclose(cyl.state.pressure_pa, expected, rtol=1e-6)


def test_bleed_is_choked_above_the_critical_ratio_and_zero_at_atmosphere() -> None:
    par = CylinderParameters()
    assert par.bleed_mass_flow_kg_s(ATMOSPHERIC_PRESSURE_PA) == 0.0
    p1, p2 = 3.0e5, 6.0e5  # both choked into atmosphere: linear in upstream pressure
    assert par.bleed_mass_flow_kg_s(p2) / par.bleed_mass_flow_kg_s(p1) == pytest.approx(2.0)


def test_friction_holds_a_piston_pushed_less_than_coulomb() -> None:
    par = CylinderParameters(bleed_discharge_area_m2=0.0, coulomb_friction_n=20.0)
    y = 0.05
    p = par.equilibrium_pressure_pa(y) + 10.0 / par.piston_area_m2  # 10 N < 20 N
    cyl = Cylinder(par, CylinderState(p, y, 0.0))
    cyl.step(0.2, 0.0)
    assert cyl.state.position_m == pytest.approx(y, abs=1e-12)
    p = par.equilibrium_pressure_pa(y) + 40.0 / par.piston_area_m2  # 40 N > 20 N: moves
    cyl = Cylinder(par, CylinderState(p, y, 0.0))
    cyl.step(0.05, 0.0)
    assert cyl.state.position_m > y + 1e-5


def test_end_stop_keeps_the_piston_within_the_stroke() -> None:
    par = CylinderParameters()
    cyl = Cylinder(par)
    for _ in range(200):
        cyl.step(0.01, 2e-3)  # full flow for 2 s: pushes against the extended stop
        assert 0.0 <= cyl.state.position_m <= par.stroke_m
    assert cyl.state.position_m == pytest.approx(par.stroke_m)


@pytest.mark.parametrize('bad', [dict(moving_mass_kg=0.0), dict(stroke_m=-1.0),
                                 dict(bore_diameter_m=math.nan), dict(coulomb_friction_n=-1)])
def test_bad_parameters_are_refused_by_name(bad) -> None:
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name):
        CylinderParameters(**bad)


def test_unknown_parameter_names_are_refused() -> None:
    with pytest.raises(ValueError, match='bore_diamter_m'):
        CylinderParameters.from_dict({'bore_diamter_m': 0.02})


def _closed_loop(setpoints: list[tuple[float, float]], duration_s: float,
                 valve_lag_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Controller + plant with an idealised valve (first-order lag of one PWM period)."""
    plant = CylinderParameters()
    cyl, ctl = Cylinder(plant), PositionController(plant=plant)
    dt, flow = 0.005, 0.0
    t = np.arange(0.0, duration_s, dt)
    y = np.empty_like(t)
    for k, tk in enumerate(t):
        ref = [s for start, s in setpoints if tk >= start][-1]
        cmd = ctl.update(ref, cyl.state.position_m, cyl.state.velocity_m_s, dt)
        assert 0.0 <= cmd <= ctl.gains.max_mass_flow_kg_s
        flow += (cmd - flow) * dt / valve_lag_s
        cyl.step(dt, flow)
        y[k] = cyl.state.position_m
    return t, y


def test_position_steps_settle_within_a_millimetre() -> None:
    steps = [(0.0, 0.02), (3.0, 0.06), (6.0, 0.04)]
    t, y = _closed_loop(steps, 9.0)
    for (start, ref), end in zip(steps, [3.0, 6.0, 9.0]):
        settled = (t > end - 0.5) & (t < end)
        assert np.all(np.abs(y[settled] - ref) < 1e-3), (ref, y[settled][-1])


def test_controller_rejects_non_finite_feedback() -> None:
    with pytest.raises(ValueError, match='position_m'):
        PositionController().update(0.02, math.nan, 0.0, 0.01)
    with pytest.raises(ValueError, match='kp_kg_s_per_m'):
        ControllerGains(kp_kg_s_per_m=-1.0)


def test_valve_fed_chamber_never_exceeds_the_supply() -> None:
    """(C7): with the valve held open the chamber tends to the supply pressure, not beyond."""
    from valve_model_pkg.model import load_parameters
    plant = CylinderParameters(bleed_discharge_area_m2=0.0)
    cyl = Cylinder(plant, valve_params=load_parameters())
    supply = 4.0e5
    for _ in range(300):
        cyl.step_with_valve(0.01, 0.33e-3, supply)
        assert cyl.chamber_gauge_pressure_pa <= supply + 1.0
    assert cyl.chamber_gauge_pressure_pa == pytest.approx(supply, rel=1e-3)
    # Above the supply the flow reverses.
    cyl.state = CylinderState(ATMOSPHERIC_PRESSURE_PA + 6.0e5, plant.stroke_m, 0.0)
    cyl.step_with_valve(1e-3, 0.33e-3, supply)
    assert cyl.last_valve_flow_kg_s < 0.0


def test_closed_loop_through_the_real_valve_and_map_tolerates_transport_delay() -> None:
    """Controller -> flow_to_duty inversion -> valve model (50 Hz PWM) -> cylinder, with
    80 ms of feedback delay (what node scheduling can add): every step ends within 1 mm."""
    from valve_model_pkg.pneumatics.closed_loop import simulate_closed_loop
    goals = [(0.02, 3.0), (0.06, 3.0), (0.04, 3.0)]
    r = simulate_closed_loop(goals, feedback_delay_s=0.08)
    end = 0.0
    for goal, hold in goals:
        end += hold
        tail = (r.t_s > end - 0.8) & (r.t_s <= end)
        assert np.all(np.abs(r.position_m[tail] - goal) < 1e-3), (goal, r.position_m[tail][-1])
    assert np.max(r.chamber_pressure_pa) - ATMOSPHERIC_PRESSURE_PA <= 4.0e5 + 1.0
    assert np.all((r.duty >= 0.0) & (r.duty <= 1.0))
