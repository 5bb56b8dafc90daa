"""The generator's family of drive electronics (tests/datagen/electronics.py) does what each
form says, its interval-mean coil voltage is exact, and its records carry what they claim.

The expectations are independent of the code under test where they can be: peak ends from
the truth model's own solver (LSODA) on a plain 24 V step, capacitor voltages and mean
chopper voltages from closed forms, the coil's voltage balance from the flux linkage of
eq. (4).
"""
from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from datagen.bench import write_pwm_record, write_step_records
from datagen.cache import operation_dataset
from datagen.electronics import FORMS, DipPeak, DipRisePeak, DriveElectronics, \
    FreewheelRelease, PiChopperHold, ReducedPwmHold, ThresholdPeak, \
    TimerPeak, ZenerRelease
from datagen.operation import PwmSchedule, simulate_operation
from datagen.truth import TruthValve, simulate_truth

_RISE_S = 0.0073 + 0.02
_N = 6
#: 50 Hz, duty 0.5, after 20 ms at rest (period starts off the 25 us integration grid).
_HALF = PwmSchedule(tuple(0.0073 + 0.02 * k for k in range(_N)), (50.0,) * _N,
                    (0.0,) + (0.5,) * (_N - 1))
#: The main PWM high from 27.3 ms on (duty 1: no falling edge).
_ON = PwmSchedule((0.0073, _RISE_S), (50.0, 50.0), (0.0, 1.0))
_VS = 24.0


def _rises(schedule: PwmSchedule, end_s: float) -> np.ndarray:
    return np.array([t for t, kind in schedule.edges(end_s) if kind == 'rise'])


def _first_step_reference(t_end_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The paper's valve under 24 V from rest (the first peak phase), LSODA, 1 us grid."""
    ts = np.arange(0.0, t_end_s, 1e-6)
    ref = simulate_truth(TruthValve(), [(0.0, _VS)], float(ts[-1]), ts, 4e5)
    return ts, ref.current_a


def test_timer_ends_the_peak_a_fixed_time_after_each_rising_edge() -> None:
    e = DriveElectronics(peak=TimerPeak(duration_s=4.6e-3))
    tr = simulate_operation(TruthValve(), _HALF, 0.1, circuit=e)
    rises = _rises(_HALF, 0.1)
    np.testing.assert_allclose(np.array(tr.boost_ends_s) - rises, 4.6e-3, atol=1e-12)


def test_threshold_ends_the_peak_where_the_current_crosses_it() -> None:
    e = DriveElectronics(peak=ThresholdPeak(current_a=0.7))
    tr = simulate_operation(TruthValve(), _ON, 0.036, circuit=e)
    ts, ref = _first_step_reference(8e-3)
    crossing = ts[np.argmax(ref >= 0.7)]          # after the stroke: the current rises again
    assert len(tr.boost_ends_s) == 1
    assert tr.boost_ends_s[0] - _RISE_S == pytest.approx(crossing, abs=2e-6)


@pytest.mark.parametrize('peak', [DipPeak(dip_a=0.02), DipRisePeak(dip_a=0.01, rise_a=0.002),
                                  DipRisePeak(dip_a=0.01, rise_a=0.0, clock_hz=20_000.0)])
def test_dip_detectors_end_the_peak_where_their_rule_says(peak) -> None:
    tr = simulate_operation(TruthValve(), _ON, 0.036, circuit=DriveElectronics(peak=peak))
    # the detector's rule applied to the LSODA current on the detector's own sample grid
    period = 1.0 / peak.clock_hz if peak.clock_hz else 25e-6
    grid = np.arange(1, int(10e-3 / period)) * period
    ts, ref = _first_step_reference(10e-3)
    i = np.interp(grid, ts, ref)
    armed_at = int(np.argmax(i < np.maximum.accumulate(i) - peak.dip_a))
    if isinstance(peak, DipPeak):
        expected = grid[armed_at]
    else:
        valley = np.minimum.accumulate(i[armed_at:])
        expected = grid[armed_at + int(np.argmax(i[armed_at:] > valley + peak.rise_a))]
    assert tr.boost_ends_s[0] - _RISE_S == pytest.approx(expected, abs=1.01 * period)


def _steady_hold(tr, settle_s: float = 3e-3) -> np.ndarray:
    """Hold-phase samples at least ``settle_s`` after the end of their peak phase."""
    mask = tr.phase == 'hold'
    for end in tr.boost_ends_s:
        mask &= ~((tr.t_s >= end) & (tr.t_s < end + settle_s))
    return mask


@pytest.mark.parametrize('off_v', [0.0, -_VS])
def test_pi_chopper_holds_its_set_point(off_v: float) -> None:
    hold = PiChopperHold(current_a=0.45, kp_per_a=20.0 if off_v == 0 else 8.0,
                         ki_per_a_s=2000.0 if off_v == 0 else 800.0, off_voltage_v=off_v)
    tr = simulate_operation(TruthValve(), _ON, 0.08, circuit=DriveElectronics(hold=hold))
    # the PI zero cancels the coil pole: what is left after the peak decays with kp/ki
    steady = _steady_hold(tr, 0.04)
    # the controller samples the current at each period start (every other step)
    starts = steady & (np.round(tr.t_s * hold.frequency_hz, 6) % 1 == 0)
    assert starts.sum() > 100
    i = tr.current_a[starts]
    assert abs(i.mean() - 0.45) < 3e-4
    assert np.abs(i - 0.45).max() < 1e-3
    # it chops: on at every period start, and the mean voltage over whole intervals of
    # steady hold is R I (the flux no longer changes), between off_v and the supply
    assert np.all(tr.coil_voltage_v[starts] == _VS)
    in_hold = np.interp(tr.sample_t_s, tr.t_s, steady.astype(float)) == 1.0
    in_hold &= np.interp(tr.sample_t_s - 1e-3, tr.t_s, steady.astype(float)) == 1.0
    assert in_hold.sum() >= 5
    v_mean = tr.interval_mean_coil_voltage_v[in_hold]
    np.testing.assert_allclose(v_mean, TruthValve().resistance_ohm *
                               tr.interval_mean_current_rk4_a[in_hold], atol=1e-3)
    assert np.all(v_mean < 0.5 * _VS)


def test_hysteresis_hold_stays_in_its_band() -> None:
    e = FORMS['timer_hysteresis_zener']
    h = e.hold
    tr = simulate_operation(TruthValve(), _HALF, 0.1, circuit=e)
    i = tr.current_a[_steady_hold(tr)]
    slack = _VS / 0.14 / h.clock_hz          # one clock period of the steepest slope
    assert i.min() > h.current_a - 0.5 * h.band_a - slack
    assert i.max() < h.current_a + 0.5 * h.band_a + slack
    off = tr.coil_voltage_v[_steady_hold(tr)]
    assert set(np.unique(off)) == {h.off_voltage_v, _VS}


def test_reduced_pwm_applies_its_duty_exactly() -> None:
    hold = ReducedPwmHold(duty=0.3, frequency_hz=20_000.0, off_voltage_v=-0.7)
    tr = simulate_operation(TruthValve(), _ON, 0.05, circuit=DriveElectronics(hold=hold))
    start = tr.boost_ends_s[0]
    # 1 ms intervals that begin at a chopper period start after the peak phase
    inside = tr.sample_t_s - 1e-3 >= math.ceil(start * 20_000.0) / 20_000.0
    expected = 0.3 * _VS + 0.7 * -0.7
    np.testing.assert_allclose(tr.interval_mean_coil_voltage_v[inside], expected, atol=1e-9)
    assert inside.sum() >= 15


def test_fast_decay_falls_faster_than_slow_and_stops_at_zero() -> None:
    # duty 0: after the peak the chopper stays in its off state (the decay itself)
    falls = {}
    for off_v in (0.0, -_VS):
        e = DriveElectronics(hold=ReducedPwmHold(duty=0.0, off_voltage_v=off_v))
        tr = simulate_operation(TruthValve(), _ON, 0.05, circuit=e)
        after = tr.t_s >= tr.boost_ends_s[0]
        i0 = tr.current_a[after][0]
        falls[off_v] = tr.t_s[after][np.argmax(tr.current_a[after] < 0.5 * i0)] - \
            tr.boost_ends_s[0]
        if off_v < 0.0:
            # blocked at zero: the terminal opens, nothing negative
            zero = after & (tr.t_s > tr.boost_ends_s[0] + 3 * falls[off_v])
            assert np.all(tr.current_a[zero] == 0.0)
            assert np.all(tr.coil_voltage_v[zero] == 0.0)
    assert falls[-_VS] < falls[0.0] / 3.0


def test_zener_clamps_until_zero_current() -> None:
    e = DriveElectronics(release=ZenerRelease(clamp_v=36.0))
    tr = simulate_operation(TruthValve(), _HALF, 0.1, circuit=e)
    release = tr.phase == 'release'
    assert release.sum() > 10
    assert np.all(tr.coil_voltage_v[release] == -36.0)
    assert np.all(tr.current_a[release] > 0.0)
    blocked = (tr.phase == 'blocked') & (tr.t_s > _RISE_S)
    assert blocked.sum() > 100 and np.all(tr.current_a[blocked] == 0.0)
    # the current is gone within L i / V_z of a few ms, far sooner than with a diode
    for fall in [t for t, kind in _HALF.edges(0.1) if kind == 'fall']:
        window = (tr.t_s > fall) & (tr.t_s < fall + 2e-3)
        assert np.any(tr.phase[window] == 'blocked'), fall


def test_freewheel_diode_decays_slowly_at_its_drop() -> None:
    e = DriveElectronics(release=FreewheelRelease(diode_drop_v=0.7))
    tr = simulate_operation(TruthValve(), _HALF, 0.1, circuit=e)
    release = tr.phase == 'release'
    assert np.all(tr.coil_voltage_v[release] == -0.7)
    fall = [t for t, kind in _HALF.edges(0.1) if kind == 'fall'][0]
    window = (tr.t_s > fall) & (tr.t_s < fall + 3e-3)
    assert np.all(tr.phase[window] == 'release') and tr.current_a[window].min() > 0.1


def test_capacitor_charged_in_the_peak_phase_only() -> None:
    e = FORMS['dip_rise_pi_fast_cap_peak']
    c = e.release
    tr = simulate_operation(TruthValve(), _HALF, 0.04, circuit=e)
    peak_s = tr.boost_ends_s[0] - _RISE_S
    fall = _RISE_S + 0.01
    after = np.flatnonzero(tr.t_s > fall)[:40]
    # empty at the start, charged for the peak phase only, held through the hold phase
    v0 = c.voltage_v * (1.0 - math.exp(-peak_s / c.charge_time_s))
    expected = -v0 * np.exp(-(tr.t_s[after] - fall) / c.discharge_time_s)
    on = tr.phase[after] == 'release'
    assert on.sum() > 20
    np.testing.assert_allclose(tr.coil_voltage_v[after][on], expected[on], rtol=1e-9)


def test_reverse_blocking_diode() -> None:
    unblocked = FORMS['dip_pi_slow_cap_unblocked']
    tr_open = simulate_operation(TruthValve(), _HALF, 0.07, circuit=unblocked)
    tr_blocked = simulate_operation(TruthValve(), _HALF, 0.07,
                                    circuit=replace(unblocked, reverse_blocking=True))
    assert tr_open.current_a.min() < -0.1
    assert 'blocked' not in set(tr_open.phase[tr_open.t_s > _RISE_S])
    assert tr_blocked.current_a.min() == 0.0
    assert np.any(tr_blocked.phase == 'blocked')


@pytest.mark.parametrize('form, moving', [(f, False) for f in sorted(FORMS)] + [
    ('generator_default', True), ('dip_rise_pi_fast_cap_peak', True)])
def test_interval_mean_voltage_satisfies_the_coil_balance(form: str, moving: bool) -> None:
    # mean(V) dt = R mean(i) dt + psi(end) - psi(start), psi = L(x) i (eq. 4, no effect);
    # a spool held by a pretension far beyond the magnet's force is the bare coil
    valve = TruthValve() if moving else replace(TruthValve(), pretension_m=0.05)
    tr = simulate_operation(valve, _HALF, 0.05, circuit=FORMS[form])
    per = int(round(1e-3 / (tr.t_s[1] - tr.t_s[0])))
    ends = np.arange(0, tr.t_s.size, per)
    psi = np.array([valve.inductance(x) for x in tr.position_m[ends]]) * tr.current_a[ends]
    lhs = tr.interval_mean_coil_voltage_v * 1e-3
    rhs = valve.resistance_ohm * tr.interval_mean_current_rk4_a * 1e-3 + np.diff(psi)
    assert np.abs(tr.interval_mean_coil_voltage_v).max() > 5.0
    # 5e-6 V in the mean: a zero-current event resets the current to 0 from within the
    # event's 1 ns tolerance, the RK4 step's own error is smaller; a moving spool's landing
    # on a stop resets its position likewise (dL/dx i dx: 1e-4 V)
    np.testing.assert_allclose(lhs, rhs, rtol=0.0, atol=1e-7 if moving else 5e-9)
    # the records' trapezoid means of the current agree to a few uA
    np.testing.assert_allclose(tr.interval_mean_current_a, tr.interval_mean_current_rk4_a,
                               rtol=0.0, atol=3e-5)
    if moving:
        assert tr.position_m.max() == pytest.approx(valve.stroke_m)


def test_stiction_delays_the_breakaway_not_the_sliding() -> None:
    ts = np.arange(0.0, 8e-3, 1e-6)

    def run(friction: float, stiction: float) -> tuple[float, float]:
        v = replace(TruthValve(), friction_n=friction, stiction_n=stiction)
        x = simulate_truth(v, [(0.0, _VS)], float(ts[-1]), ts, 4e5).position_m
        return ts[np.argmax(x > 1e-12)], ts[np.argmax(x >= v.stroke_m - 1e-9)]
    start_s, open_s = run(2.0, 2.5)
    start_k, open_k = run(2.5, 0.0)         # kinetic = static = 2.5 N
    start_0, _ = run(2.0, 0.0)
    assert start_s == pytest.approx(start_k, abs=1e-5)     # breaks away at 2.5 N
    assert start_s > start_0 + 2e-5
    assert open_s < open_k                                  # but slides against 2 N


def _read_csv(path: str | Path) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    lines = Path(path).read_text(encoding='utf-8').splitlines()
    meta = dict(ln[2:].split(': ', 1) for ln in lines if ln.startswith('# '))
    body = [ln for ln in lines if not ln.startswith('#')]
    data = np.array([[float(v) for v in ln.split(',')] for ln in body[1:]])
    return meta, {name: data[:, k] for k, name in enumerate(body[0].split(','))}


def test_operation_record_with_mean_voltage_and_quantisation(tmp_path: Path) -> None:
    truth = operation_dataset(tmp_path, seed=2, noise_a=3e-3, duration_s=0.15,
                              electronics='timer_hysteresis_zener', coil_voltage_mean=True,
                              lsb_a=0.01)
    meta, cols = _read_csv(truth['file'])
    assert meta['experiment'] == 'operation' and meta['current_averaging'] == 'interval_mean'
    assert list(cols)[-1] == 'coil_voltage_mean'
    codes = cols['current'] / 0.01
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-6)
    assert codes.min() >= 0 and codes.max() <= 255
    v = cols['coil_voltage_mean']
    assert np.all(v[cols['duty'] == 0.0][:20] == 0.0)      # at rest: nothing applied
    assert v.max() <= _VS and v.min() >= -36.0 and v.max() > 5.0
    again = json.loads(Path(truth['file']).with_suffix('.truth.json').read_text())
    assert again['electronics']['peak']['form'] == 'timer' and again['lsb_a'] == 0.01


def test_pwm_record_columns(tmp_path: Path) -> None:
    truth = write_pwm_record(tmp_path, 'p', circuit=FORMS['suite_like'], duration_s=0.07,
                             rate_hz=50_000.0, noise_a=1e-3, coil_voltage=True)
    meta, cols = _read_csv(truth['file'])
    assert meta['experiment'] == 'pwm' and float(meta['sample_rate_hz']) == 50_000.0
    np.testing.assert_allclose(np.diff(cols['t']), 2e-5, rtol=1e-6)
    assert set(np.unique(cols['voltage'])) == {0.0, _VS}
    # the bench's main PWM is not the coil voltage: the chopper shows only in the latter
    high = cols['voltage'] == _VS
    assert np.any(cols['coil_voltage'][high] == 0.0)
    assert cols['coil_voltage'].min() < -10.0


def test_step_records_with_stiction(tmp_path: Path) -> None:
    with_s = write_step_records(tmp_path, 's', effect='coulomb_friction_stiction',
                                noise_a=0.0)
    without = write_step_records(tmp_path, 'n', effect='coulomb_friction', noise_a=0.0)
    assert with_s['declared_effect'] == 'coulomb_friction'
    assert with_s['valve']['stiction_n'] == 2.5 and with_s['valve']['friction_n'] == 2.0
    for role in ('fit', 'validate'):
        assert with_s['files'][role]['motion_start_s'] > \
            without['files'][role]['motion_start_s']
    _, cols = _read_csv(with_s['fit'][0])
    assert set(np.unique(cols['voltage'])) == {0.0, _VS}
