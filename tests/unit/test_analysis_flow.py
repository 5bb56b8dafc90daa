"""The loop's flow numerics (analysis.flow_calibration, analysis.flow_prediction): the flow
scale C_d C_A recovered from a chamber filled through a valve of known scale (simulated
here with eq. 12 and the chamber's mass balance written out independently), window means,
the map's opening and the flow area at full opening."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from valve_model_pkg.analysis import (FlowPrediction, FlowPredictionError, RunChamber,
                                      calibrate_flow_scale, full_opening_area_m2,
                                      map_opening_m, window_means)
from valve_model_pkg.interface import ATMOSPHERIC_PRESSURE_PA
from valve_model_pkg.maps import load_map
from valve_model_pkg.model import load_parameters
from valve_model_pkg.pneumatics.cylinder import CylinderParameters
from valve_model_pkg.recording import TopicData

SUPPLY_GAUGE_PA = 4e5
#: The valve of the synthetic chamber delivers this fraction of the suite set's C_d C_A.
TRUE_SCALE = 0.7


def _eq12_per_unit(p_up: float, p_down: float, temp: float, r_gas: float,
                   gamma: float) -> float:
    """Eq. (12) per unit C_d C_A x [kg/(s m^2)] for absolute pressures p_up >= p_down."""
    ratio = p_down / p_up
    crit = (2.0 / (gamma + 1.0)) ** (gamma / (gamma - 1.0))
    if ratio <= crit:
        return p_up / math.sqrt(temp) * math.sqrt(
            gamma / r_gas * (2.0 / (gamma + 1.0)) ** ((gamma + 1.0) / (gamma - 1.0)))
    return p_up / math.sqrt(temp) * math.sqrt(
        2.0 * gamma / (r_gas * (gamma - 1.0))
        * (ratio ** (2.0 / gamma) - ratio ** ((gamma + 1.0) / gamma)))


def _opening_m(t: np.ndarray | float) -> np.ndarray | float:
    """A valve that opens to 0.1 mm and closes again once a second."""
    return 0.1e-3 * (1.0 - np.cos(2.0 * np.pi * t)) / 2.0


def _synthetic_chamber(product_m: float, cyl: CylinderParameters) -> RunChamber:
    """A chamber of constant volume filled through the valve and bled to the atmosphere:
    V dp/dt = n R T (P x phi_v(p_s, p) - B phi_b(p)), sampled every 5 ms for 4 s."""
    par = load_parameters()
    temp, r_gas, gamma = par.supply_temperature_k, par.gas_constant_j_per_kg_k, \
        par.heat_capacity_ratio
    position_m = 0.05
    volume = cyl.dead_volume_m3 + math.pi * cyl.bore_diameter_m ** 2 / 4.0 * position_m
    p_sup = SUPPLY_GAUGE_PA + ATMOSPHERIC_PRESSURE_PA

    def rhs(t: float, y: np.ndarray) -> list[float]:
        p = y[0]
        valve = product_m * _opening_m(t) * _eq12_per_unit(p_sup, p, temp, r_gas, gamma)
        bleed = cyl.bleed_discharge_area_m2 * _eq12_per_unit(
            p, ATMOSPHERIC_PRESSURE_PA, temp, r_gas, gamma) if p > ATMOSPHERIC_PRESSURE_PA \
            else 0.0
        return [cyl.polytropic_exponent * r_gas * temp / volume * (valve - bleed)]
    t = np.arange(1, 801) * 0.005
    sol = solve_ivp(rhs, (0.0, t[-1]), [ATMOSPHERIC_PRESSURE_PA], t_eval=t, rtol=1e-9,
                    atol=1e-4, max_step=0.02)
    assert sol.success
    empty = TopicData('/valve/state', 'valve_msgs/msg/ValveState', np.zeros(0, np.int64))
    return RunChamber(t_s=t, position_m=np.full_like(t, position_m),
                      pressure_pa=sol.y[0] - ATMOSPHERIC_PRESSURE_PA, duty=np.zeros_like(t),
                      pwm_frequency_hz=50.0, supply_pressure_pa=SUPPLY_GAUGE_PA, state=empty)


def test_the_flow_scale_of_a_valve_is_recovered_from_its_chamber() -> None:
    suite = load_parameters()
    prior = suite.discharge_coefficient * suite.orifice_area_gradient_m
    cyl = CylinderParameters()
    chamber = _synthetic_chamber(TRUE_SCALE * prior, cyl)
    assert chamber.pressure_pa.max() > 0.5e5           # the chamber does fill
    cal = calibrate_flow_scale(chamber, _opening_m(chamber.t_s), suite, cyl)
    assert cal.prior_product_m == pytest.approx(prior)
    assert cal.ratio == pytest.approx(TRUE_SCALE, rel=1e-3)
    assert cal.interval_m[0] < cal.product_m < cal.interval_m[1]
    # C_d kept, C_A scaled
    assert cal.params.discharge_coefficient == suite.discharge_coefficient
    assert cal.params.orifice_area_gradient_m == pytest.approx(
        TRUE_SCALE * suite.orifice_area_gradient_m, rel=1e-3)
    assert cal.balance_error_after_pct < cal.balance_error_before_pct
    assert cal.windows == 16 and cal.window_s == 0.25
    doc = cal.to_json()
    assert doc['ratio'] == cal.ratio and doc['cylinder']['polytropic_exponent'] == 1.2
    assert doc['full_opening_area_m2'] == pytest.approx(
        TRUE_SCALE * full_opening_area_m2(suite), rel=1e-3)


def test_full_opening_area_is_cd_ca_times_the_stroke() -> None:
    p = load_parameters().replace(discharge_coefficient=0.5, stroke_m=0.3e-3)
    assert full_opening_area_m2(p) == pytest.approx(0.5 * p.orifice_area_gradient_m * 0.3e-3)


def test_the_maps_opening_runs_from_closed_to_the_full_stroke() -> None:
    par = load_parameters()
    duty = np.linspace(0.0, 1.0, 21)
    x = map_opening_m(load_map(), par, duty, 50.0, SUPPLY_GAUGE_PA)
    assert x[0] == 0.0 and x[-1] == pytest.approx(par.stroke_m)
    assert np.all(np.diff(x) >= 0.0) and np.all(x <= par.stroke_m)


def test_window_means() -> None:
    t = np.arange(1000) * 1e-3                   # 1 ms samples over 1 s
    values = np.floor(t / 0.1)                   # window i holds the value i
    starts = np.arange(12) * 0.1                 # two windows beyond the samples
    means = window_means(t, values, starts, 0.1)
    np.testing.assert_allclose(means[:10], np.arange(10), atol=1e-12)
    assert np.all(np.isnan(means[10:]))


def test_the_flow_prediction_json_names_each_set() -> None:
    err = FlowPredictionError(2e-3, 4500, 4.5, 'bag', 40, 0.1, {
        'nominal': FlowPrediction(1e-4, 5.0, 1e-3, 1.1e-3),
        'identified': FlowPrediction(2e-5, 1.0, 1.08e-3, 1.1e-3)})
    doc = err.to_json()
    assert doc['nominal']['rms_pct'] == 5.0 and doc['identified']['rms_kg_s'] == 2e-5
    assert doc['windows'] == 40 and doc['window_s'] == 0.1 and doc['full_flow_kg_s'] == 2e-3
