"""ValveStepper: streaming semantics, glitch-free commands, agreement with simulate_pwm."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import (
    ElectronicsConfig, ParameterError, ValveParameters, ValveSample, ValveStepper,
    orifice_mass_flow, simulate_pwm,
)

P = ValveParameters()


def test_initial_sample_is_closed_and_deenergised() -> None:
    s = ValveStepper(P)
    smp = s.sample()
    assert isinstance(smp, ValveSample)
    assert smp.t_s == 0.0
    assert smp.coil_current_a == 0.0
    assert smp.spool_position_m == 0.0
    assert smp.position_avg_m == 0.0
    assert smp.mass_flow_kg_s == 0.0
    assert smp.supply_pressure_pa == 4.0e5


def test_stepper_matches_offline_simulation() -> None:
    res = simulate_pwm(P, ElectronicsConfig(), 0.4, 50.0, 0.1, sample_rate_hz=1000.0)
    s = ValveStepper(P, duty=0.4, pwm_frequency_hz=50.0)
    cur = []
    pos = []
    for t in res.t_s:
        s.advance_to(float(t))
        smp = s.sample()
        cur.append(smp.coil_current_a)
        pos.append(smp.spool_position_m)
    # chunked integration lands on the same edges: identical up to rounding
    np.testing.assert_allclose(cur, res.coil_current_a, atol=1e-6)
    np.testing.assert_allclose(pos, res.spool_position_m, atol=1e-9)
    smp = s.sample()
    assert smp.position_avg_m == pytest.approx(res.period_avg_position_m[-1], rel=1e-6)
    assert smp.mass_flow_kg_s == pytest.approx(
        float(orifice_mass_flow(smp.position_avg_m, 4e5, 0.0, P)), rel=1e-12)
    assert smp.mass_flow_kg_s > 0.0


def test_command_applies_at_next_period_start() -> None:
    s = ValveStepper(P, duty=0.0, pwm_frequency_hz=50.0)
    s.advance_to(0.005)
    s.set_command(0.5, 50.0)
    s.advance_to(0.0199)
    smp = s.sample()
    assert smp.duty == 0.0           # not yet: the running period keeps its duty
    assert smp.coil_current_a == 0.0
    assert smp.coil_voltage_v == 0.0
    s.advance_to(0.0201)
    smp = s.sample()
    assert smp.duty == 0.5
    assert smp.coil_voltage_v == pytest.approx(24.0)
    assert smp.coil_current_a > 0.0


def test_frequency_change_keeps_running_period() -> None:
    s = ValveStepper(P, duty=0.5, pwm_frequency_hz=50.0)
    s.advance_to(0.001)
    s.set_command(0.5, 100.0)
    # the first 20 ms period continues: high until 10 ms, low until 20 ms
    s.advance_to(0.0150)
    assert s.sample().pwm_frequency_hz == 50.0
    assert s.sample().coil_voltage_v <= 0.0
    s.advance_to(0.0201)
    assert s.sample().pwm_frequency_hz == 100.0
    s.advance_to(0.0262)   # 100 Hz: the second period is low from 25 to 30 ms
    assert s.sample().coil_voltage_v <= 0.0


def test_reset_and_pressures() -> None:
    s = ValveStepper(P, duty=1.0)
    s.advance_to(0.01)
    assert s.sample().spool_position_m == pytest.approx(P.stroke_m)
    s.set_pressures(6.0e5, 1.0e5)
    assert s.sample().supply_pressure_pa == 6.0e5
    s.reset()
    smp = s.sample()
    assert smp.t_s == 0.0 and smp.spool_position_m == 0.0
    assert smp.supply_pressure_pa == 4.0e5


def test_advance_backwards_is_a_no_op() -> None:
    s = ValveStepper(P, duty=0.4)
    s.advance_to(0.01)
    before = s.sample()
    s.advance_to(0.005)
    assert s.sample() == before


@pytest.mark.parametrize('duty, freq, match', [
    (1.5, 50.0, r'duty must be in \[0, 1\], got 1\.5'),
    (-0.1, 50.0, r'duty must be in \[0, 1\]'),
    (float('nan'), 50.0, r'duty must be in \[0, 1\], got nan'),
    (0.5, 0.0, r'pwm_frequency_hz must be positive, got 0\.0'),
    (0.5, float('inf'), r'pwm_frequency_hz must be positive, got inf'),
])
def test_bad_commands_refused(duty: float, freq: float, match: str) -> None:
    s = ValveStepper(P)
    with pytest.raises(ParameterError, match=match):
        s.set_command(duty, freq)


def test_bad_pressure_and_time_refused() -> None:
    s = ValveStepper(P)
    with pytest.raises(ParameterError, match='supply_pa must be a finite gauge pressure'):
        s.set_pressures(float('nan'), 0.0)
    with pytest.raises(ParameterError, match='t_s must be finite'):
        s.advance_to(float('inf'))
