"""Flow -> duty: eq. (12) solved for the opening and the static map inverted."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from valve_model_pkg.maps import (ATMOSPHERIC_PRESSURE_PA, DutyMap, FlowStatus,
                                  FlowToDutyInverter, OrificeConstants, flow_per_opening,
                                  invalid_flow_reason)
from valve_model_pkg.maps.synthetic import linear_map, linear_position
from valve_model_pkg.model import load_parameters, orifice_mass_flow

REPO_ROOT = Path(__file__).resolve().parents[2]
PARAMS = load_parameters()
CONST = OrificeConstants.from_parameters(PARAMS)


@pytest.fixture(scope='module')
def inv() -> FlowToDutyInverter:
    return FlowToDutyInverter(linear_map(), 50.0)


def _q(r: float, supply_pa: float, output_pa: float = 0.0) -> float:
    k, _ = flow_per_opening(supply_pa, output_pa, CONST)
    return r * k * PARAMS.stroke_m


@pytest.mark.parametrize('supply_pa, output_pa, choked', [
    (4e5, 0.0, True), (6e5, 1e5, True), (4e5, 3e5, False), (1e5, 0.5e5, False),
    (0.5e5, -0.5e5, True),
])
def test_flow_per_opening_is_eq12_of_the_model(supply_pa: float, output_pa: float,
                                               choked: bool) -> None:
    k, is_choked = flow_per_opening(supply_pa, output_pa, CONST)
    x = 0.2e-3
    assert is_choked == choked
    assert k * x == pytest.approx(float(orifice_mass_flow(x, supply_pa, output_pa, PARAMS)),
                                  rel=1e-12)


def test_eq12_uses_absolute_pressures() -> None:
    k, choked = flow_per_opening(4e5, 0.0, CONST)
    p_abs = 4e5 + ATMOSPHERIC_PRESSURE_PA
    expected = 0.0404184 * CONST.discharge_coefficient * CONST.orifice_area_gradient_m * \
        p_abs / math.sqrt(CONST.supply_temperature_k)
    assert choked and k == pytest.approx(expected, rel=1e-5)
    # a temperature override scales with 1/sqrt(T)
    k_hot, _ = flow_per_opening(4e5, 0.0, CONST, supply_temperature_k=4 * 293.15)
    assert k_hot == pytest.approx(0.5 * k * math.sqrt(293.15 / CONST.supply_temperature_k))


@pytest.mark.parametrize('supply_pa, output_pa', [(0.0, 0.0), (2e5, 3e5), (-101325.0, 0.0)])
def test_no_forward_pressure_difference(inv: FlowToDutyInverter, supply_pa: float,
                                        output_pa: float) -> None:
    res = inv.compute(1e-3, supply_pa, output_pa)
    assert res.status == FlowStatus.NO_PRESSURE and res.duty == 0.0
    assert res.achievable_mass_flow == 0.0


@pytest.mark.parametrize('supply_pa', [2e5, 4e5, 3e5, 4.6e5, 1e5])
@pytest.mark.parametrize('r', [0.05, 0.2, 0.5, 0.77, 0.999])
def test_inverts_the_ramp_exactly_on_and_between_grid_pressures(
        inv: FlowToDutyInverter, supply_pa: float, r: float) -> None:
    """The synthetic ramps shift linearly with pressure: horizontal interpolation is exact."""
    res = inv.compute(_q(r, supply_pa), supply_pa, 0.0)
    assert res.status == FlowStatus.OK, res.message
    assert res.position_fraction == pytest.approx(r)
    assert float(linear_position(res.duty, 50.0, supply_pa)) == pytest.approx(r, abs=1e-9)
    assert res.achievable_mass_flow == pytest.approx(res.requested_mass_flow)
    assert res.choked and res.pwm_frequency_hz == 50.0


def test_subsonic_needs_a_larger_opening(inv: FlowToDutyInverter) -> None:
    q = _q(0.3, 4e5)
    choked = inv.compute(q, 4e5, 0.0)
    subsonic = inv.compute(q, 4e5, 3e5)
    assert not subsonic.choked and subsonic.position_fraction > choked.position_fraction
    assert subsonic.duty > choked.duty


def test_saturation_high_and_low(inv: FlowToDutyInverter) -> None:
    high = inv.compute(_q(1.3, 4e5), 4e5)
    assert high.status == FlowStatus.SATURATED_HIGH and high.duty == 1.0
    assert high.achievable_mass_flow == pytest.approx(high.max_mass_flow)
    assert high.max_mass_flow == pytest.approx(_q(1.0, 4e5))
    assert 'beyond reach' in high.message
    zero = inv.compute(0.0, 4e5)
    assert zero.status == FlowStatus.SATURATED_LOW and zero.duty == 0.0


@pytest.mark.parametrize('zero_fraction, fraction_of_open, status, duty', [
    (0.5, 0.3, FlowStatus.SATURATED_LOW, 0.0),
    (0.5, 0.7, FlowStatus.DEAD_BAND_LIFTED, 0.15),
    (0.0, 0.01, FlowStatus.DEAD_BAND_LIFTED, 0.15),
    (1.0, 0.99, FlowStatus.SATURATED_LOW, 0.0),
])
def test_dead_band_rule(zero_fraction: float, fraction_of_open: float, status: FlowStatus,
                        duty: float) -> None:
    """At 4 bar the ramp starts at 14 %: 15 % is the first grid duty that opens."""
    inv = FlowToDutyInverter(linear_map(), 50.0, zero_fraction=zero_fraction)
    r_open = float(linear_position(0.15, 50.0, 4e5))
    res = inv.compute(_q(fraction_of_open * r_open, 4e5), 4e5)
    assert res.status == status, res.message
    assert res.duty == pytest.approx(duty)
    if status == FlowStatus.DEAD_BAND_LIFTED:
        assert res.achievable_mass_flow == pytest.approx(_q(r_open, 4e5))


def test_positive_flow_never_gets_a_duty_that_leaves_the_valve_closed() -> None:
    """Random flows and pressures: the duty is 0 or one at which the valve opens."""
    rng = np.random.default_rng(7)
    dmap = linear_map(dead_band=0.123, shift_per_bar=0.013)
    for zf in (0.0, 0.5):
        inv = FlowToDutyInverter(dmap, 50.0, zero_fraction=zf)
        for _ in range(2000):
            p = rng.uniform(0.2e5, 6e5)
            q = _q(rng.uniform(0.0, 0.05) if rng.random() < 0.7 else rng.uniform(0, 1.2), p)
            res = inv.compute(q, p)
            assert res.duty == 0.0 or linear_position(
                res.duty, 50.0, p, dead_band=0.123, shift_per_bar=0.013) > 0.0, (p, q, res)


def test_pressure_outside_the_map_uses_the_nearest_curve(inv: FlowToDutyInverter) -> None:
    res = inv.compute(_q(0.5, 8e5), 8e5)
    assert res.status == FlowStatus.OK and 'above the map' in res.message
    assert float(linear_position(res.duty, 50.0, 6e5)) == pytest.approx(0.5)


def test_jump_of_the_curve_takes_the_nearer_side() -> None:
    """A curve that leaps from 20 % to 60 % of the stroke at 40 % duty."""
    base = linear_map(supply_pressures_pa=(4e5,), pwm_frequencies_hz=(50.0,))
    d = base.duty
    x = np.clip((d - 0.1) / 0.75, 0.0, 1.0)
    x = np.where(d < 0.4, np.minimum(x, 0.2 * (d - 0.1) / 0.3), np.maximum(x, 0.6))
    x = np.clip(x, 0.0, 1.0)
    extra = [(np.array([0.39875, 0.4]), np.array([0.2 * 0.29875 / 0.3, 0.6]))]
    dmap = DutyMap(duty=d, supply_pressures_pa=base.supply_pressures_pa,
                   pwm_frequencies_hz=base.pwm_frequencies_hz, position_fraction=x[None, None],
                   parameters=base.parameters, electronics=base.electronics,
                   extra_points=extra, refinement={'min_spacing': 0.00125,
                                                   'jump_threshold': 0.02})
    jumps = dmap.jumps(0, 0)
    assert len(jumps) == 1 and jumps[0][0] == pytest.approx(0.39875)
    inv = FlowToDutyInverter(dmap, 50.0)
    low = inv.compute(_q(0.3, 4e5), 4e5)        # nearer to 0.2 than to 0.6
    high = inv.compute(_q(0.5, 4e5), 4e5)
    assert low.duty == pytest.approx(0.39875) and high.duty == pytest.approx(0.4)
    assert low.achievable_mass_flow == pytest.approx(_q(0.2 * 0.29875 / 0.3, 4e5))
    assert 'jump of the map' in low.message and high.status == FlowStatus.OK


def test_frequency_must_be_in_the_map() -> None:
    with pytest.raises(KeyError, match='75 Hz is not in the map'):
        FlowToDutyInverter(linear_map(), 75.0)
    with pytest.raises(ValueError, match='zero_fraction'):
        FlowToDutyInverter(linear_map(), 50.0, zero_fraction=1.5)


@pytest.mark.parametrize('value, ok', [
    (0.0, True), (2e-3, True), (float('nan'), False), (float('inf'), False),
    (-1e-6, False), ('1', False), (True, False),
])
def test_invalid_flow_reason(value: object, ok: bool) -> None:
    assert (invalid_flow_reason(value) is None) == ok


def test_status_codes_equal_the_message_constants() -> None:
    text = (REPO_ROOT / 'valve_msgs' / 'msg' / 'FlowToDutyStatus.msg').read_text()
    constants = {m.group(1): int(m.group(2))
                 for m in re.finditer(r'uint8 STATUS_(\w+)\s*=\s*(\d+)', text)}
    assert constants == {s.name: int(s) for s in FlowStatus}


@pytest.mark.parametrize('supply_pa', [3e5, 4e5, 5.2e5])
def test_forward_direction_is_the_inverse(inv: FlowToDutyInverter, supply_pa: float) -> None:
    """duty_to_position (used by the flow check between grid pressures) undoes the inversion."""
    for duty in (0.05, 0.2, 0.45, 0.7, 0.95):
        expected = float(linear_position(duty, 50.0, supply_pa))
        if duty < inv.opening_duty(supply_pa):
            expected = 0.0
        assert inv.duty_to_position(duty, supply_pa) == pytest.approx(expected, abs=1e-9)
