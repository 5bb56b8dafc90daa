"""Subsystem equations against hand-computed values: eqs. (2)-(12)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from valve_model_pkg.model import ValveParameters, inductance, magnetic_force, orifice_mass_flow
from valve_model_pkg.model.electrical import current_derivative
from valve_model_pkg.model.magnetics import (
    MU_0, equivalent_length, flux_linkage, inductance_slope,
)
from valve_model_pkg.model.mechanics import active_force, pressure_force
from valve_model_pkg.model.orifice import critical_pressure_ratio

P = ValveParameters()
KL = P.coil_turns ** 2 * P.core_area_m2 * P.relative_permeability * MU_0


def test_inductance_eq_2_and_4() -> None:
    # l_eq = l_c + 2 mu_r (x_t - x): 0.115 + 240 * 0.4e-3 = 0.211 m at x = 0
    assert equivalent_length(P, 0.0) == pytest.approx(0.211)
    assert equivalent_length(P, P.stroke_m) == pytest.approx(0.115 + 240 * 0.07e-3)
    np.testing.assert_allclose(inductance(P, [0.0, P.stroke_m]),
                               [KL / 0.211, KL / 0.1318], rtol=1e-12)
    assert float(inductance(P, 0.0)) == pytest.approx(0.08933, rel=1e-3)


def test_inductance_slope_eq_6_matches_finite_difference() -> None:
    x = np.array([0.0, 1e-4, 3e-4])
    h = 1e-9
    fd = (inductance(P, x + h) - inductance(P, x - h)) / (2 * h)
    np.testing.assert_allclose(inductance_slope(P, x), fd, rtol=1e-6)
    ind = inductance(P, x)
    np.testing.assert_allclose(inductance_slope(P, x),
                               2 * P.relative_permeability * ind ** 2 / KL, rtol=1e-12)


def test_force_eq_8() -> None:
    i, x = 0.5, 1e-4
    ind = float(inductance(P, x))
    expected = ind ** 2 * i ** 2 / (P.coil_turns ** 2 * P.core_area_m2 * MU_0)
    assert float(magnetic_force(P, i, x)) == pytest.approx(expected, rel=1e-12)
    # threshold of motion at 4 bar: F_m(0) = k delta - F_prs, current about 0.534 A
    f_needed = P.spring_stiffness_n_per_m * P.spring_pretension_m - float(
        pressure_force(P, 4e5))
    i_open = math.sqrt(f_needed / float(magnetic_force(P, 1.0, 0.0)))
    assert i_open == pytest.approx(0.534, abs=0.002)


def test_saturated_force_is_coenergy_derivative_and_tends_to_eq_8() -> None:
    sat = P.replace(saturation_coefficient_per_a=1.0)
    i, x, h = 0.8, 2e-4, 1e-9

    def coenergy(xx: float) -> float:
        ii = np.linspace(0.0, i, 20001)
        lam = flux_linkage(sat, ii, xx)
        return float(np.sum(0.5 * (lam[1:] + lam[:-1]) * np.diff(ii)))

    fd = (coenergy(x + h) - coenergy(x - h)) / (2 * h)
    assert float(magnetic_force(sat, i, x)) == pytest.approx(fd, rel=1e-6)
    assert float(magnetic_force(sat, i, x)) < float(magnetic_force(P, i, x))
    weak = P.replace(saturation_coefficient_per_a=1e-7)
    assert float(magnetic_force(weak, i, x)) == pytest.approx(
        float(magnetic_force(P, i, x)), rel=1e-6)


def test_current_derivative_eq_7() -> None:
    v, i, x, xd = 24.0, 0.4, 1e-4, 0.5
    ind = float(inductance(P, x))
    expected = (v - P.coil_resistance_ohm * i) / ind - 2 * P.relative_permeability * ind * xd \
        * i / KL
    di, i_t = current_derivative(P, v, i, x, xd)
    assert di == pytest.approx(expected, rel=1e-12)
    assert i_t == i


def test_eddy_and_leakage_change_the_circuit_as_designed() -> None:
    v, i, x = 24.0, 0.2, 0.0
    ind = float(inductance(P, x))
    r = P.coil_resistance_ohm
    leak = P.replace(leakage_inductance_h=0.01)
    di, _ = current_derivative(leak, v, i, x, 0.0)
    assert di == pytest.approx((v - r * i) / (ind + 0.01), rel=1e-12)
    eddy = P.replace(eddy_conductance_s=0.01)
    di, i_t = current_derivative(eddy, v, i, x, 0.0)
    v_branch = (v - r * i) / (1 + r * 0.01)
    assert di == pytest.approx(v_branch / ind, rel=1e-12)
    assert i_t == pytest.approx(i + 0.01 * v_branch, rel=1e-12)
    hot = current_derivative(P, v, i, x, 0.0, temperature_rise_k=50.0)[0]
    assert hot == pytest.approx((v - r * (1 + 0.00393 * 50) * i) / ind, rel=1e-12)


def test_pressure_force_eq_10() -> None:
    # (A1 - A2) P_sup: negative, closes the valve; A3 = A4 cancels P_out
    assert float(pressure_force(P, 4e5, 3e5)) == pytest.approx((26.57e-6 - 35.25e-6) * 4e5)
    assert float(pressure_force(P, 4e5)) == pytest.approx(-3.472, abs=1e-3)
    assert float(active_force(P, 20.0, 0.0, 0.0)) == pytest.approx(20.0 - 11.0)


def test_orifice_choked_branch_eq_12() -> None:
    x, ps = 2e-4, 4e5
    expected = 0.0405 * P.discharge_coefficient * P.orifice_area_gradient_m * x * (
        ps + 101325.0) / math.sqrt(P.supply_temperature_k)
    # the constant is computed from gamma and R: 0.04042 vs the printed 0.0405
    assert float(orifice_mass_flow(x, ps, 0.0, P)) == pytest.approx(expected, rel=3e-3)
    assert critical_pressure_ratio(1.4) == pytest.approx(0.528, abs=5e-4)


def test_orifice_subsonic_branch_uses_2_over_gamma() -> None:
    x, p_up, p_dn = 2e-4, 3e5, 2.5e5  # gauge; ratio above 0.528
    pu, pd = p_up + 101325.0, p_dn + 101325.0
    g, rg = 1.4, 287.0
    r = pd / pu
    expected = P.discharge_coefficient * P.orifice_area_gradient_m * x * pu / math.sqrt(
        P.supply_temperature_k) * math.sqrt(2 * g / (rg * (g - 1)) * (
            r ** (2 / g) - r ** ((g + 1) / g)))
    assert float(orifice_mass_flow(x, p_up, p_dn, P)) == pytest.approx(expected, rel=1e-12)


def test_orifice_continuity_monotonicity_and_reverse_flow() -> None:
    crit = critical_pressure_ratio(1.4)
    pu = 5e5 + 101325.0
    below = orifice_mass_flow(1e-4, 5e5, pu * crit * (1 - 1e-9) - 101325.0, P)
    above = orifice_mass_flow(1e-4, 5e5, pu * crit * (1 + 1e-9) - 101325.0, P)
    assert float(below) == pytest.approx(float(above), rel=1e-6)
    flows = orifice_mass_flow(1e-4, 5e5, np.linspace(0.0, 5e5, 50), P)
    assert np.all(np.diff(flows) <= 1e-15)
    assert float(flows[-1]) == 0.0
    assert float(orifice_mass_flow(1e-4, 1e5, 3e5, P)) == pytest.approx(
        -float(orifice_mass_flow(1e-4, 3e5, 1e5, P)))
    assert float(orifice_mass_flow(0.0, 5e5, 0.0, P)) == 0.0
    # linear in the position (the paper's x_bar)
    assert float(orifice_mass_flow(2e-4, 5e5, 0.0, P)) == pytest.approx(
        2 * float(orifice_mass_flow(1e-4, 5e5, 0.0, P)))
