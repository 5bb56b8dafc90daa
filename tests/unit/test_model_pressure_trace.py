"""Time-varying supply and output pressures carried by an InputTrace."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import (
    InputTrace, ParameterError, ValveParameters, ValveStepper, orifice_mass_flow,
    simulate_trace_batch,
)

P = ValveParameters()
T = np.arange(1, 101) * 1e-3
#: supply pressure course: 1 bar, 6 bar from 30 ms, 2 bar from 70 ms (output 0.5 bar)
CHANGES_S = [0.0, 0.03, 0.07]
SUPPLY_PA = [1.0e5, 6.0e5, 2.0e5]


def _pressure_trace() -> InputTrace:
    return InputTrace.pwm_commands(CHANGES_S, 0.4, 50.0, supply_pressure_pa=SUPPLY_PA,
                                   output_pressure_pa=0.5e5)


def test_a_constant_pressure_trace_is_the_scalar_form_bit_for_bit() -> None:
    carried = InputTrace.pwm_commands([0.0], 0.4, 50.0, supply_pressure_pa=3e5,
                                      output_pressure_pa=1e5)
    res = simulate_trace_batch(P, carried, T, sampling='interval_mean')
    ref = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], 0.4, 50.0), T,
                               sampling='interval_mean', supply_pressure_pa=3e5,
                               output_pressure_pa=1e5)
    for name in ('coil_current_a', 'coil_voltage_v', 'spool_position_m'):
        assert np.array_equal(getattr(res, name), getattr(ref, name))
    assert res.supply_pressure_pa[0] == 3e5 and res.output_pressure_pa[0] == 1e5


def test_pressure_changes_act_at_once_as_the_stepper_set_pressures() -> None:
    res = simulate_trace_batch(P, _pressure_trace(), T).run(0)
    stepper = ValveStepper(P, duty=0.4, pwm_frequency_hz=50.0, supply_pressure_pa=1e5,
                           output_pressure_pa=0.5e5)
    cur, pos = [], []
    for t_k in T:
        stepper.advance_to(t_k)
        for t_c, p_sup in zip(CHANGES_S[1:], SUPPLY_PA[1:]):
            if abs(t_k - t_c) < 1e-12:
                stepper.set_pressures(p_sup, 0.5e5)
        sample = stepper.sample()
        cur.append(sample.coil_current_a)
        pos.append(sample.spool_position_m)
    # the trace applies a change 3 ps before its time: differences of that order only
    np.testing.assert_allclose(res.coil_current_a, cur, rtol=0, atol=1e-8)
    np.testing.assert_allclose(res.spool_position_m, pos, rtol=0, atol=1e-10)


def test_the_supply_pressure_moves_the_spool_from_its_change_on() -> None:
    res = simulate_trace_batch(P, _pressure_trace(), T).run(0)
    low = simulate_trace_batch(P, InputTrace.pwm_commands([0.0], 0.4, 50.0), T,
                               supply_pressure_pa=1e5, output_pressure_pa=0.5e5).run(0)
    before = T < 0.03 - 1e-9
    assert np.array_equal(res.spool_position_m[before], low.spool_position_m[before])
    high = (T > 0.04) & (T < 0.07)
    # eq. (10): the supply pressure pushes the spool closed (A_1 < A_2): less opening
    assert res.spool_position_m[high].mean() < low.spool_position_m[high].mean() - 1e-6


def test_the_mass_flow_uses_the_pressures_in_force_at_each_sample() -> None:
    t = np.arange(1, 41) * 1e-3
    trace = InputTrace.coil_voltage([0.0, 0.02], 24.0, supply_pressure_pa=[4e5, 5e5],
                                    output_pressure_pa=[0.0, 2e5])
    res = simulate_trace_batch(P, trace, t).run(0)
    late = t >= 0.02
    expected = orifice_mass_flow(res.position_avg_m, np.where(late, 5e5, 4e5),
                                 np.where(late, 2e5, 0.0), P)
    np.testing.assert_allclose(res.mass_flow_kg_s, expected, rtol=1e-15)
    assert expected[late][-1] != pytest.approx(expected[~late][-1], rel=1e-3)


def test_with_pressures_adds_a_course_at_its_own_times() -> None:
    base = InputTrace.pwm_commands([0.0, 0.05], [0.3, 0.7], 50.0)
    trace = base.with_pressures([0.02, 0.05, 0.08], [2e5, 3e5, 4e5], 0.0)
    np.testing.assert_array_equal(trace.t_s, [0.0, 0.02, 0.05, 0.08])
    np.testing.assert_array_equal(trace.duty, [0.3, 0.3, 0.7, 0.7])
    np.testing.assert_array_equal(trace.supply_pressure_pa, [2e5, 2e5, 3e5, 4e5])
    np.testing.assert_array_equal(trace.output_pressure_pa, np.zeros(4))
    sup, out = trace.pressures_at(np.array([0.01, 0.05, 0.0799, 0.1]))
    np.testing.assert_array_equal(sup, [2e5, 3e5, 3e5, 4e5])
    assert trace.key() != base.key()


def test_equal_coil_voltage_levels_merge_only_where_the_pressures_are_equal() -> None:
    trace = InputTrace.coil_voltage([0.0, 1e-3, 2e-3], 24.0, supply_pressure_pa=[1e5, 1e5, 2e5],
                                    output_pressure_pa=0.0)
    np.testing.assert_array_equal(trace.t_s, [0.0, 2e-3])
    np.testing.assert_array_equal(trace.supply_pressure_pa, [1e5, 2e5])


@pytest.mark.parametrize('make, match', [
    (lambda: InputTrace.pwm_commands([0.0], 0.4, supply_pressure_pa=1e5),
     'give both supply_pressure_pa and output_pressure_pa'),
    (lambda: InputTrace.pwm_commands([0.0], 0.4, supply_pressure_pa=-2e5,
                                     output_pressure_pa=0.0), 'above -1 bar'),
    (lambda: InputTrace.step(24.0).with_pressures([0.0], 1e5, 0.0), 'step trace'),
    (lambda: simulate_trace_batch(P, _pressure_trace(), T, supply_pressure_pa=4e5),
     'the traces carry the pressures'),
    (lambda: simulate_trace_batch([P, P], [_pressure_trace(), InputTrace.pwm_commands(
        [0.0], 0.4)], T), 'all carry pressures or none'),
    (lambda: InputTrace.pwm_commands([0.0], 0.4).pressures_at(T), 'carries no pressures'),
])
def test_bad_pressure_inputs_are_refused(make, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        make()
