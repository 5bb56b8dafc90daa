"""Close semantics of the model (docs/safety.md, "Close semantics"): duty 0 acts at once.

A duty of 0 ends the running main PWM high phase at the command's model time whatever the
PWM frequency; any other duty or frequency change waits for the next period start.
"""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import InputTrace, ValveParameters, ValveStepper, simulate_trace_batch

P = ValveParameters()
#: Model time within which the coil voltage must be <= 0 after a duty-0 command [s].
DEENERGISE_BOUND_S = 2e-3
#: Spool closing time after the switch-off: capacitor pulse, current decay, spring [s].
CLOSE_BOUND_S = 10e-3


def _open_at_low_frequency(freq: float = 0.1, duty: float = 0.9) -> ValveStepper:
    s = ValveStepper(P, duty=duty, pwm_frequency_hz=freq)
    s.advance_to(1.0)           # well inside the 9 s high phase: held open by the chopper
    smp = s.sample()
    assert smp.duty == duty and smp.spool_position_m == pytest.approx(P.stroke_m)
    assert smp.coil_current_a > 0.3
    return s


@pytest.mark.parametrize('freq', [0.1, 0.02])
def test_duty_zero_deenergises_at_once_and_the_spool_closes(freq: float) -> None:
    s = _open_at_low_frequency(freq)
    t_cmd = s.t_s
    s.set_command(0.0, freq)
    smp = s.sample()
    assert smp.duty == 0.0                         # in force at the command's instant
    assert smp.coil_voltage_v <= 0.0               # capacitor pulse (negative) at once
    t_closed = None
    for k in range(1, 201):                        # 0.1 ms grid for 20 ms
        s.advance_to(t_cmd + k * 1e-4)
        smp = s.sample()
        if k * 1e-4 <= DEENERGISE_BOUND_S:
            assert smp.coil_voltage_v <= 0.0, smp
        if t_closed is None and smp.spool_position_m == 0.0:
            t_closed = smp.t_s - t_cmd
    assert t_closed is not None and t_closed <= CLOSE_BOUND_S, t_closed
    assert s.sample().coil_current_a < 0.1        # decaying through the coil (L/R)
    # and it stays closed for the rest of the (long) period
    s.advance_to(t_cmd + 2.0)
    assert s.sample().spool_position_m == 0.0 and s.sample().duty == 0.0


def test_after_a_stop_a_new_duty_waits_for_the_period_grid() -> None:
    s = ValveStepper(P, duty=0.5, pwm_frequency_hz=50.0)
    s.advance_to(0.005)                            # inside the first high phase
    s.set_command(0.0, 50.0)
    assert s.sample().duty == 0.0 and s.sample().coil_voltage_v <= 0.0
    s.advance_to(0.007)
    s.set_command(0.5, 50.0)                       # non-zero: next period start (20 ms)
    s.advance_to(0.0199)
    assert s.sample().duty == 0.0 and s.sample().coil_voltage_v <= 0.0
    s.advance_to(0.0201)
    assert s.sample().duty == 0.5 and s.sample().coil_voltage_v == pytest.approx(24.0)


def test_stop_in_the_low_phase_and_repeated_zeros_change_nothing_else() -> None:
    s = ValveStepper(P, duty=0.3, pwm_frequency_hz=50.0)
    s.advance_to(0.010)                            # low phase of the first period
    v_before = s.sample().coil_voltage_v
    s.set_command(0.0, 50.0)
    s.set_command(0.0, 50.0)
    smp = s.sample()
    assert smp.duty == 0.0 and smp.coil_voltage_v == v_before   # the pulse goes on as it was


def test_zero_at_a_period_start_is_the_period_start_s_business() -> None:
    """A trace that commands 0 exactly at a period start is unchanged by the close rule."""
    t = np.arange(1, 81) * 1e-3
    trace = InputTrace.pwm_commands([0.0, 0.04], [0.5, 0.0], 50.0)
    res = simulate_trace_batch(P, trace, t)
    s = ValveStepper(P, duty=0.5, pwm_frequency_hz=50.0)
    cur = []
    for k, tk in enumerate(t):
        s.advance_to(float(tk))
        cur.append(s.sample().coil_current_a)
        if k == 38:
            s.set_command(0.0, 50.0)               # at 39 ms: pending for the 40 ms start
    np.testing.assert_allclose(cur, res.coil_current_a[0], atol=1e-9)


def test_trace_and_stepper_agree_on_a_stop_mid_period() -> None:
    t = np.arange(1, 121) * 1e-3
    trace = InputTrace.pwm_commands([0.0, 0.025], [0.8, 0.0], 20.0)
    res = simulate_trace_batch(P, trace, t)
    s = ValveStepper(P, duty=0.8, pwm_frequency_hz=20.0)
    cur, pos = [], []
    for k, tk in enumerate(t):
        s.advance_to(float(tk))
        smp = s.sample()
        cur.append(smp.coil_current_a)
        pos.append(smp.spool_position_m)
        if k == 24:
            s.set_command(0.0, 20.0)               # at 25 ms, inside the 40 ms high phase
    np.testing.assert_allclose(cur, res.coil_current_a[0], atol=1e-6)
    np.testing.assert_allclose(pos, res.spool_position_m[0], atol=1e-9)
    assert pos[-1] == 0.0 and res.coil_voltage_v[0, 25] <= 0.0
