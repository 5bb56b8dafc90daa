"""Inputs the model's kernel cannot integrate get a named error, never a ZeroDivisionError
(model/kernel.py), and the builders of drive inputs never hand it a zero-length period
(model/trace.py InputTrace.pwm_commands, identification DriveInput.from_periods)."""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.errors import KernelInputError, ParameterError
from valve_model_pkg.identification.measurement import DriveInput
from valve_model_pkg.model import load_parameters, simulate_trace_batch
from valve_model_pkg.model import kernel as k
from valve_model_pkg.model.electronics import ElectronicsConfig
from valve_model_pkg.model.parameters import PARAMETER_FIELDS
from valve_model_pkg.model.trace import InputTrace

PARAMS = load_parameters()
T_SAMPLES = np.linspace(0.0, 0.06, 61)


def _trace_batch(seg_t, seg_period, t_samp=T_SAMPLES) -> None:
    n = len(seg_t)
    raw = np.atleast_2d(PARAMS.to_vector())
    out = np.zeros((1, len(t_samp), k.N_OUT))
    k.trace_batch(raw, ElectronicsConfig().to_vector(), np.asarray(seg_t, dtype=float),
                  np.full(n, 24.0), np.full(n, 0.5), np.asarray(seg_period, dtype=float),
                  np.array([4e5]), np.array([0.0]), np.asarray(t_samp, dtype=float),
                  k.DEFAULT_H_FREE_S, k.DEFAULT_H_STOP_S, out, np.zeros((1, 2)),
                  parallel=False)


def test_a_zero_length_pwm_period_is_refused_by_name() -> None:
    with pytest.raises(KernelInputError, match=r'PWM period\[1\] = 0 s'):
        _trace_batch([0.0, 0.01], [0.02, 0.0])


@pytest.mark.parametrize('seg_t, t_samp, what', [
    ([0.0, 0.01, 0.01], T_SAMPLES, r'input change times\[2\] = 0\.01 s does not follow'),
    ([0.0, 0.01, 0.02], np.r_[T_SAMPLES[:5], T_SAMPLES[4:]], r'sample times\[5\]'),
])
def test_intervals_of_zero_length_are_refused_by_name(seg_t, t_samp, what) -> None:
    with pytest.raises(KernelInputError, match=what):
        _trace_batch(seg_t, [0.02] * len(seg_t), t_samp)


def test_a_zero_divisor_inside_the_rows_is_a_named_error() -> None:
    raw = np.atleast_2d(PARAMS.to_vector())
    raw[0, PARAMETER_FIELDS.index('thermal_resistance_k_per_w')] = 5.0
    raw[0, PARAMETER_FIELDS.index('thermal_time_constant_s')] = 0.0  # dT/dt = (.) / tau
    with pytest.raises(KernelInputError, match='division by zero') as info:
        simulate_trace_batch(raw, InputTrace.coil_voltage([0.0, 0.01], [0.0, 24.0]),
                             T_SAMPLES, validate=False)
    assert not isinstance(info.value, ZeroDivisionError)


def test_pwm_commands_refuse_a_period_below_a_nanosecond() -> None:
    with pytest.raises(ParameterError, match=r'pwm_frequency_hz\[0\] = 1e\+300 Hz'):
        InputTrace.pwm_commands([0.0, 0.02], 0.5, [1e300, 50.0], 24.0)
    InputTrace.pwm_commands([0.0, 0.02], 0.5, [1e6, 50.0], 24.0)  # 1 us: a period


def test_a_repeated_period_start_is_merged_not_a_zero_length_period() -> None:
    # the record shows two period starts at 20 ms; the second's command holds from there
    drive = DriveInput.from_periods([0.0, 0.02, 0.02, 0.04], [0.5, 0.5, 0.3, 0.3],
                                    [50.0] * 4, 24.0)
    merged = DriveInput.from_periods([0.0, 0.02, 0.04], [0.5, 0.3, 0.3], [50.0] * 3, 24.0)
    assert np.all(np.diff(drive.period_starts_s) > 0.0)
    np.testing.assert_array_equal(drive.period_starts_s, merged.period_starts_s)
    np.testing.assert_array_equal(drive.period_duty, merged.period_duty)
    traces = [InputTrace.pwm_commands(d.t_s, d.duty, d.pwm_frequency_hz, d.supply_voltage_v)
              for d in (drive, merged)]
    currents = [simulate_trace_batch(PARAMS, tr, T_SAMPLES).coil_current_a for tr in traces]
    np.testing.assert_array_equal(currents[0], currents[1])
