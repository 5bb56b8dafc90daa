"""The drive electronics family (model/electronics.py) against analytic expectations.

Each form is checked where the coil is a fixed inductance (the spool held on a stop), so
the current follows an RL circuit whose solution is known: a clamp or fast decay gives
i(t) = (i_0 + V/R) exp(-t/tau) - V/R with tau = L/R; the ends of the peak phase are
compared with their rule applied independently to the current the model computes.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from valve_model_pkg.model import (
    ElectronicsConfig, InputTrace, ValveParameters, simulate_trace_batch,
)
from valve_model_pkg.model import kernel as K
from valve_model_pkg.model.magnetics import inductance

P = ValveParameters()
R = P.coil_resistance_ohm
L_CLOSED = float(inductance(P, 0.0))
L_OPEN = float(inductance(P, P.stroke_m))
CHOP_S = 1.0 / 20e3


def _run(e: ElectronicsConfig, t: np.ndarray, *, duty: float = 1.0, freq: float = 50.0,
         supply_v: float = 24.0, sampling: str = 'instant'):
    """One run of main PWM commands through ``e``, sampled at ``t``."""
    trace = InputTrace.pwm_commands([0.0], duty, freq, supply_v)
    return simulate_trace_batch(P, trace, t, electronics=e, sampling=sampling).run(0)


def _boost_end(e: ElectronicsConfig, first_edge_s: float = 0.0, until_s: float = 0.02
               ) -> float:
    """Time the first peak phase ends (the kernel's record of it), s."""
    p = K.derive_parameters(P.to_vector())
    d = K.new_drive_state(24.0, 1.0, 1.0, first_edge_s, 4e5)
    K.advance(p, e.to_vector(), np.zeros(K.N_Y), d, until_s)
    return float(d[K.D_BOOST_END])


def _rl(t: np.ndarray, i_0: float, volt: float, ind: float) -> np.ndarray:
    """Current of an RL circuit under a constant voltage from i_0 at t = 0, A."""
    return (i_0 - volt / R) * np.exp(-t * R / ind) + volt / R


# --- release -------------------------------------------------------------------------
@pytest.mark.parametrize('release, field, volt', [('zener', 'zener_voltage_v', 30.0),
                                                  ('diode', 'diode_drop_v', 0.7)])
def test_a_clamp_release_decays_as_the_rl_circuit_under_its_voltage_until_zero(
        release: str, field: str, volt: float) -> None:
    # 6 V without current control: 0.46 A, below the opening current, so L stays L(0)
    e = ElectronicsConfig(current_control=False, release=release, **{field: volt})
    t_fall = 0.05
    t = t_fall + np.arange(0, 4001) * 10e-6
    res = _run(e, np.concatenate(([0.01], t)), duty=0.5, freq=10.0, supply_v=6.0)
    assert np.all(res.spool_position_m == 0.0)
    i, v = res.coil_current_a[1:], res.coil_voltage_v[1:]
    i_0 = i[0]
    assert i_0 == pytest.approx(6.0 / R, rel=1e-3)
    tau = L_CLOSED / R
    t_zero = tau * math.log(1.0 + R * i_0 / volt)  # where the RL solution crosses zero
    assert t_zero < t[-1] - t_fall
    s = t - t_fall
    on = s < t_zero - 1e-9
    np.testing.assert_allclose(i[on], _rl(s[on], i_0, -volt, L_CLOSED), rtol=0, atol=1e-9)
    assert np.all(v[on] == -volt)
    # the slope at the edge: (-V - R i_0) / L, i.e. -V_z / L plus the resistive drop
    assert (i[1] - i[0]) / 10e-6 == pytest.approx((-volt - R * i_0) / L_CLOSED, rel=2e-3)
    after = s > t_zero + 1e-9
    assert np.all(i[after] == 0.0) and np.all(v[after] == 0.0)


def test_a_capacitor_charged_in_the_peak_phase_holds_the_charge_of_that_phase() -> None:
    e = ElectronicsConfig(release='capacitor_peak')
    t_peak = _boost_end(e)
    assert 2e-3 < t_peak < 6e-3
    res = _run(e, np.array([0.004, 0.008]), duty=0.4)  # the falling edge at 8 ms
    expected = -24.0 * (1.0 - math.exp(-t_peak / e.capacitor_charge_time_s))
    assert res.coil_voltage_v[1] == pytest.approx(expected, rel=1e-12)
    whole = _run(ElectronicsConfig(), np.array([0.008]), duty=0.4)
    assert whole.coil_voltage_v[0] == pytest.approx(-24.0 * (1.0 - math.exp(-8.0)),
                                                    rel=1e-12)


# --- hold ------------------------------------------------------------------------------
def test_fast_decay_falls_as_the_rl_circuit_under_minus_the_supply() -> None:
    e = ElectronicsConfig(hold_decay='fast')
    t = 0.03 + np.arange(0, 501) * 1e-6
    res = _run(e, t)
    assert np.all(res.spool_position_m == P.stroke_m)
    off = res.coil_voltage_v == -24.0
    assert np.all((res.coil_voltage_v == 24.0) | off)
    starts = np.flatnonzero(off[1:] & ~off[:-1]) + 1
    assert len(starts) >= 5
    for k in starts:
        n = np.argmax(~off[k:]) or len(off) - k  # samples until the chopper is on again
        s = t[k:k + n] - t[k]
        np.testing.assert_allclose(res.coil_current_a[k:k + n],
                                   _rl(s, res.coil_current_a[k], -24.0, L_OPEN),
                                   rtol=0, atol=1e-11)


def test_diode_decay_applies_minus_the_diode_drop_while_the_chopper_is_off() -> None:
    e = ElectronicsConfig(hold_decay='diode', diode_drop_v=0.9)
    res = _run(e, 0.03 + np.arange(0, 201) * 1e-6)
    volts = set(np.unique(res.coil_voltage_v))
    assert volts == {24.0, -0.9}
    assert res.coil_current_a.mean() == pytest.approx(0.5, abs=0.01)


def test_the_hysteresis_current_stays_within_its_band() -> None:
    band, clock = 0.04, 100e3
    e = ElectronicsConfig(hold='hysteresis', hysteresis_band_a=band,
                          comparator_frequency_hz=clock)
    t = 0.01 + np.arange(0, 5001) * 2e-6
    res = _run(e, t)
    assert np.all(res.spool_position_m == P.stroke_m)
    i = res.coil_current_a
    lo, hi = 0.5 - band / 2, 0.5 + band / 2
    # between comparator samples the current moves on by at most one clock period's slope
    rise = (24.0 - R * lo) / L_OPEN / clock
    fall = R * hi / L_OPEN / clock
    assert i.max() <= hi + rise and i.min() >= lo - fall
    assert i.max() > hi and i.min() < lo  # it switches at the band's edges
    assert set(np.unique(res.coil_voltage_v)) == {0.0, 24.0}


def test_reduced_voltage_hold_settles_at_the_supply_times_the_duty_over_r() -> None:
    e = ElectronicsConfig(hold='pwm', hold_duty=0.3)
    t = np.arange(1, 201) * 1e-3  # 1 ms: 20 whole chopper periods, whatever their phase
    res = _run(e, t, sampling='interval_mean')
    assert np.all(res.spool_velocity_m_s[-20:] == 0.0)
    np.testing.assert_allclose(res.coil_voltage_v[-20:], 24.0 * 0.3, rtol=1e-12)
    np.testing.assert_allclose(res.coil_current_a[-20:], 24.0 * 0.3 / R, rtol=1e-6)


@pytest.mark.parametrize('block', [True, False])
def test_fast_decay_stops_at_zero_current_when_the_driver_blocks_reverse_current(
        block: bool) -> None:
    e = ElectronicsConfig(hold='pwm', hold_duty=0.05, hold_decay='fast',
                          block_reverse_current=block)
    res = _run(e, 0.03 + np.arange(0, 1001) * 1e-6)
    i, v = res.coil_current_a, res.coil_voltage_v
    if block:
        assert i.min() == 0.0
        assert np.all(v[i == 0.0] != -24.0)  # nothing conducts at zero current: 0 V
        assert np.any(i == 0.0)
    else:
        assert i.min() < -0.01


# --- peak phase ------------------------------------------------------------------------
@pytest.mark.parametrize('edge_s', [0.0, 7e-3])
def test_a_timer_ends_the_peak_phase_at_its_time(edge_s: float) -> None:
    e = ElectronicsConfig(peak_end='timer', max_boost_time_s=2.537e-3)
    assert _boost_end(e, edge_s) == pytest.approx(edge_s + 2.537e-3, abs=1e-15)


def test_the_threshold_ends_the_peak_phase_when_the_current_reaches_it() -> None:
    e = ElectronicsConfig(peak_end='threshold', peak_current_a=0.9)
    t_end = _boost_end(e)
    assert 3e-3 < t_end < 10e-3  # after the stroke's dip, before the timeout
    res = _run(e, np.array([t_end]))
    assert res.coil_current_a[0] == pytest.approx(0.9, abs=1e-9)
    before = _run(e, np.linspace(1e-5, t_end - 1e-6, 500))
    assert before.coil_current_a.max() < 0.9
    assert np.all(before.coil_voltage_v == 24.0)


def test_the_threshold_times_out_at_the_longest_peak_phase() -> None:
    e = ElectronicsConfig(peak_end='threshold', peak_current_a=5.0, max_boost_time_s=6e-3)
    assert _boost_end(e) == pytest.approx(6e-3, abs=1e-15)


def _peak_current_samples() -> np.ndarray:
    """Terminal current at the controller's samples k / 20 kHz under the full supply."""
    e = ElectronicsConfig(peak_end='timer', max_boost_time_s=0.01)
    return _run(e, np.arange(0, 200) * CHOP_S).coil_current_a


def _dip_end(i: np.ndarray, dip: float) -> int:
    """The sample that ends the peak: a rise after a fall of ``dip`` below the maximum."""
    top, dipped = i[0], False
    for k in range(1, len(i)):
        if i[k] > top:
            top = i[k]
        elif top - i[k] >= dip:
            dipped = True
        if dipped and i[k] > i[k - 1]:
            return k
    raise AssertionError('no dip')


def _dip_rise_end(i: np.ndarray, dip: float, rise: float) -> int:
    """The sample that ends the peak: ``rise`` above the minimum after the dip."""
    top, low = i[0], math.nan
    for k in range(1, len(i)):
        if math.isnan(low):
            if i[k] > top:
                top = i[k]
            elif top - i[k] >= dip:
                low = i[k]
        elif i[k] < low:
            low = i[k]
        elif i[k] - low >= rise:
            return k
    raise AssertionError('no rise')


def test_the_dip_forms_end_the_peak_at_the_sample_their_rule_names() -> None:
    i = _peak_current_samples()
    k_dip = _dip_end(i, 0.01)
    k_rise = _dip_rise_end(i, 0.01, 0.05)
    assert k_rise > k_dip
    assert _boost_end(ElectronicsConfig()) == pytest.approx(k_dip * CHOP_S, abs=1e-12)
    e = ElectronicsConfig(peak_end='dip_rise', rise_threshold_a=0.05)
    assert _boost_end(e) == pytest.approx(k_rise * CHOP_S, abs=1e-12)


# --- every form --------------------------------------------------------------------------
FORMS = {
    'timer': dict(peak_end='timer', max_boost_time_s=4e-3),
    'threshold': dict(peak_end='threshold', peak_current_a=0.8),
    'dip_rise': dict(peak_end='dip_rise'),
    'hysteresis_fast': dict(hold='hysteresis', hold_decay='fast'),
    'pwm_diode': dict(hold='pwm', hold_decay='diode'),
    'capacitor_peak': dict(release='capacitor_peak'),
    'zener': dict(release='zener'),
    'diode': dict(release='diode'),
}


@pytest.mark.parametrize('form', sorted(FORMS))
def test_every_form_runs_with_the_effects_without_forced_steps(form: str) -> None:
    params = P.replace(eddy_conductance_s=0.01, coulomb_friction_n=1.0,
                       leakage_inductance_h=0.02, restitution_coefficient=0.5)
    e = ElectronicsConfig(**FORMS[form])
    res = simulate_trace_batch(params, InputTrace.pwm_commands([0.0], 0.4, 50.0),
                               np.arange(1, 61) * 1e-3, electronics=e,
                               sampling='interval_mean').run(0)
    assert res.n_forced_steps == 0
    assert np.all(np.isfinite(res.coil_current_a))
    assert res.spool_position_m.max() > 0.9 * P.stroke_m  # the valve opens
    assert res.spool_position_m[-1] < 0.1 * P.stroke_m    # and closes


#: Releases through a path that conducts forward coil current only (the driver blocks
#: reverse current), each ending at zero current well inside the low phase.
BLOCKING_RELEASES = {
    'zener': dict(release='zener', zener_voltage_v=36.0),
    'capacitor_peak': dict(release='capacitor_peak', capacitor_voltage_v=48.0,
                           capacitor_discharge_time_s=5e-3),
}


@pytest.mark.parametrize('g_e', [1e-4, 4e-3, 2e-2])
@pytest.mark.parametrize('form', sorted(BLOCKING_RELEASES))
def test_a_blocking_driver_never_carries_reverse_terminal_current_with_eddy_currents(
        form: str, g_e: float) -> None:
    # the diodes block the terminal current i_t = (i_m + G_e v) / (1 + R G_e), not the
    # magnetising current: under -36 V or -48 V the terminal current would otherwise fall
    # to about -G_e V while i_m is still flowing
    e = ElectronicsConfig(block_reverse_current=True, **BLOCKING_RELEASES[form])
    params = P.replace(eddy_conductance_s=g_e)
    trace = InputTrace.pwm_commands([0.0], 0.3, 50.0)
    t = np.arange(1, 40001) * 1e-6
    res = simulate_trace_batch(params, trace, t, electronics=e).run(0)
    assert res.n_forced_steps == 0
    assert np.all(np.isfinite(res.coil_current_a))
    assert res.coil_current_a.min() >= 0.0
    assert res.spool_position_m.max() > 0.9 * P.stroke_m  # the valve opens
    assert res.spool_position_m[-1] < 0.1 * P.stroke_m    # and closes
    means = simulate_trace_batch(params, trace, np.arange(1, 41) * 1e-3, electronics=e,
                                 sampling='interval_mean').run(0)
    assert means.coil_current_a.min() >= 0.0


def test_the_open_terminal_lets_the_magnetising_current_decay_through_the_eddy_path(
        ) -> None:
    # the spool held closed (1 ms high phases), so L = L(0): once the Zener clamp has
    # brought the terminal current to zero, the terminal is open, the eddy path carries
    # the magnetising current, and the terminal voltage -i_m / G_e decays with L G_e
    g_e = 4e-3
    e = ElectronicsConfig(block_reverse_current=True, release='zener', zener_voltage_v=36.0)
    t = np.arange(1, 10001) * 1e-6
    res = simulate_trace_batch(P.replace(eddy_conductance_s=g_e),
                               InputTrace.pwm_commands([0.0], 0.05, 50.0), t,
                               electronics=e).run(0)
    i, v = res.coil_current_a, res.coil_voltage_v
    assert res.spool_position_m.max() == 0.0
    open_ = (t > 1e-3) & (v > -35.99) & (v < -0.5)
    k = np.flatnonzero(open_)
    assert k.size > 1000 and np.all(np.diff(k) == 1)  # one open stretch of over 1 ms
    assert np.all(i[k] == 0.0)
    assert np.all(i[(t > 1e-3) & (t < t[k[0]])] > 0.0)  # the clamp conducts until then
    tau = -1.0 / np.polyfit(t[k], np.log(-v[k]), 1)[0]
    assert tau == pytest.approx(L_CLOSED * g_e, rel=2e-3)


def test_the_default_is_the_papers_driver_and_off_the_bare_coil() -> None:
    e = ElectronicsConfig()
    forms = (e.peak_end, e.hold, e.hold_decay, e.release)
    assert forms == ('dip', 'pi', 'freewheel', 'capacitor')
    assert e.current_control and e.negative_voltage and e.block_reverse_current
    off = ElectronicsConfig.off()
    assert not off.current_control and not off.negative_voltage


@pytest.mark.parametrize('field, value, message', [
    ('peak_end', 'peak', 'peak_end must be one of'),
    ('hold', 3, 'hold must be one of'),
    ('hold_duty', 1.5, r'hold_duty must be in \[0, 1\]'),
    ('zener_voltage_v', 0.0, 'zener_voltage_v must be positive'),
    ('hysteresis_band_a', -0.1, 'hysteresis_band_a must be non-negative'),
    ('current_control', 1, 'current_control must be true or false'),
    ('diode_drop_v', math.nan, 'diode_drop_v must be finite'),
])
def test_bad_settings_are_refused_naming_the_field_and_value(field: str, value: object,
                                                             message: str) -> None:
    from valve_model_pkg.errors import ParameterError
    with pytest.raises(ParameterError, match=message):
        ElectronicsConfig(**{field: value})


def test_a_clamp_running_when_the_electronics_switch_still_ends_at_zero_current() -> None:
    from valve_model_pkg.model import ValveStepper
    stepper = ValveStepper(P, ElectronicsConfig(release='zener'), duty=0.4)
    stepper.advance_to(0.0081)  # the falling edge at 8 ms: the clamp runs
    assert stepper.sample().coil_voltage_v == -30.0
    stepper.set_electronics(ElectronicsConfig.off())  # the bench mode, at duty 0
    stepper.set_command(0.0, 50.0)
    currents = []
    for k in range(1, 120):
        stepper.advance_to(0.0081 + k * 1e-4)
        currents.append(stepper.sample().coil_current_a)
    assert min(currents) == 0.0
    assert stepper.sample().coil_voltage_v == 0.0
