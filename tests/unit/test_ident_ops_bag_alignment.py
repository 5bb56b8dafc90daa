"""A CAN-lockstep bag read for identification: the time axis rebuilt from the sequence
numbers and the main PWM grid placed where the controller has it. The emulator's PWM grid
is locked to its 1 kHz telemetry (both tick from model time 0), so a period starts exactly
at a sample time; the nominal model must then reproduce the recorded interval means
(placing the start mid-interval, or rebuilding the step from the two end stamps, puts it
tens of mA off). Fast: no identification run."""
from __future__ import annotations

import numpy as np

from valve_model_pkg.identification.bag_reader import StateColumns, measurement_from_state
from valve_model_pkg.identification.model_adapter import prepare_trace, simulate_measurement
from valve_model_pkg.identification.pwm_grid import drive_from_in_force
from valve_model_pkg.model import InputTrace, load_parameters
from valve_model_pkg.model import simulate_trace_batch as model_trace_batch

_N = 1201          # telemetry messages, 1 ms apart, from model time 0
_STEP_S = 1e-3


def _lockstep_records() -> tuple[StateColumns, np.ndarray]:
    """ValveState fields of the emulator on the simulation clock (nominal model, 50 Hz)."""
    t = np.arange(_N) * _STEP_S
    # commands given between period starts (control ticks); each latches at the next start
    t_cmd = [0.0, 0.0123, 0.0571, 0.2333, 0.6012]
    duty_cmd = [0.0, 0.30, 0.55, 0.40, 0.62]
    trace = InputTrace.pwm_commands(t_cmd, duty_cmd, [50.0] * len(t_cmd), 24.0)
    res = model_trace_batch(load_parameters(), trace, t, sampling='interval_mean',
                            supply_pressure_pa=4e5)
    starts = np.ceil(np.array(t_cmd) / 0.02) * 0.02          # where each one latches
    in_force = np.array(duty_cmd)[np.searchsorted(starts, t + 1e-12, side='right') - 1]
    # stamps on receipt with a /clock a step behind now and then, the last one included
    lag = np.where(np.arange(_N) % 7 == 3, _STEP_S, 0.0)
    lag[-1] = _STEP_S
    stamps = 100.0 + t - lag
    zeros = np.zeros(_N)
    records = StateColumns(
        frame_id=np.full(_N, 'valve'), stamp_s=stamps, log_time_s=stamps,
        sequence=np.arange(_N, dtype=float), coil_voltage_v=zeros, coil_current_a=zeros,
        spool_position_m=zeros, position_measured=np.zeros(_N, dtype=bool),
        supply_pressure_pa=np.full(_N, 4e5), output_pressure_pa=zeros,
        pwm_frequency_hz=np.full(_N, 50.0), duty=in_force.astype(float),
        coil_current_mean_a=res.coil_current_a[0].copy())
    return records, res.coil_current_a[0]


def test_lockstep_bag_time_axis_and_pwm_grid_match_the_emulator() -> None:
    records, _ = _lockstep_records()
    m = measurement_from_state('lockstep', '/valve/state', None, records)
    # one message per 1 ms step: the lagging last stamp must not shorten the step; time 0
    # is the start of the first message's interval, one step before it
    np.testing.assert_allclose(m.t_s, (np.arange(_N) + 1) * _STEP_S, atol=1e-9)
    # the first energised period starts exactly 20 ms after the first message (model time
    # 0: the grid of model time 0)
    first = m.drive.period_starts_s[m.drive.period_duty > 0][0]
    assert abs(first - m.t_s[0] - 0.020) < 1e-9
    np.testing.assert_allclose(np.diff(m.drive.period_starts_s[:6]), 0.02, atol=1e-9)


def test_nominal_model_reproduces_a_lockstep_bag_through_the_adapter() -> None:
    """Reader + adapter + nominal parameters = the recorded interval means (< 1 mA)."""
    records, recorded = _lockstep_records()
    m = measurement_from_state('lockstep', '/valve/state', None, records)
    sim, _ = simulate_measurement(load_parameters().to_vector()[None, :], prepare_trace(m))
    err = sim[0] - recorded
    assert np.max(np.abs(err[m.valid])) < 1e-3


def test_a_switch_off_does_not_swallow_the_next_period_of_the_same_duty() -> None:
    """Duty 0 seen for a while, then the same duty again: the model must pulse again."""
    t = np.arange(1, 201) * 1e-3
    duty = np.where(t > 0.0123, 0.5, 0.0)
    duty[(t > 0.0245) & (t <= 0.0323)] = 0.0      # off at once, back at the 32.3 ms start
    drive, _ = drive_from_in_force(t, duty, np.full(t.size, 100.0), 24.0)
    off = drive.off_times_s[0]
    nxt = drive.period_starts_s[drive.period_starts_s > off][0]
    before = drive.t_s < nxt
    assert drive.duty[before][-1] == 0.5 and drive.t_s[before][-1] > off


def test_messages_lost_on_the_way_are_put_back_and_each_mean_keeps_its_interval() -> None:
    """A bag that lost messages (sequence gaps): each recorded mean covers the period since
    the message before it was sent, not the whole gap; the lost ones come back as missing
    samples and the nominal model still reproduces every recorded mean (< 1 mA)."""
    records, recorded = _lockstep_records()
    lost = np.zeros(_N, dtype=bool)
    for start, n in [(31, 1), (140, 3), (415, 2), (713, 5), (1002, 1)]:
        lost[start:start + n] = True
    m = measurement_from_state('lossy', '/valve/state', None, records.select(~lost))
    assert m.n_samples == _N
    assert np.all(np.isnan(m.current_a[lost])) and np.all(np.isfinite(m.current_a[~lost]))
    assert any('12 lost messages put back' in n for n in m.notes), m.notes
    assert any('5 sequence gaps, 12 messages lost' in n for n in m.notes), m.notes
    sim, _ = simulate_measurement(load_parameters().to_vector()[None, :], prepare_trace(m))
    err = (sim[0] - recorded)[~lost & m.valid]
    assert np.max(np.abs(err)) < 1e-3


def test_a_counter_that_jumps_far_is_not_filled() -> None:
    """A publisher restart (its counter far ahead, the stamps a step on) puts nothing back."""
    records, _ = _lockstep_records()
    records.stamp_s[:] = 100.0 + np.arange(_N) * _STEP_S   # stamps that increase
    records.sequence[600:] += 10**6
    m = measurement_from_state('restart', '/valve/state', None, records)
    assert m.n_samples == _N
    assert any('1000000 messages lost' in n for n in m.notes), m.notes
    assert not any('lost messages put back' in n for n in m.notes), m.notes
