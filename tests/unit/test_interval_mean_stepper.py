"""Interval-mean telemetry of the model: ValveStepper's means are the kernel's exact integrals.

The stepper sampled once per message reports the mean coil current and voltage since the
previous message; they equal ``simulate_trace_batch(..., sampling='interval_mean')`` on the
same commands (the same integrals of the same kernel).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from valve_model_pkg.model import InputTrace, ValveParameters, ValveStepper, simulate_trace_batch

P = ValveParameters()


def _stepper_means(t: np.ndarray, commands: dict[int, tuple[float, float]],
                   first: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, list]:
    s = ValveStepper(P, duty=first[0], pwm_frequency_hz=first[1])
    cur, volt, samples = [], [], []
    for k, tk in enumerate(t):
        s.advance_to(float(tk))
        smp = s.sample()
        samples.append(smp)
        cur.append(smp.coil_current_mean_a)
        volt.append(smp.coil_voltage_mean_v)
        if k in commands:
            s.set_command(*commands[k])
    return np.array(cur), np.array(volt), samples


@pytest.mark.parametrize('rate_hz', [1000.0, 200.0])
def test_means_equal_the_exact_interval_integrals(rate_hz: float) -> None:
    t = np.arange(1, int(0.3 * rate_hz) + 1) / rate_hz
    # duty 0.4 at 50 Hz, 0.8 at 80 Hz from sample 1/3 on, a stop (duty 0) at 2/3
    k1, k2 = len(t) // 3, 2 * len(t) // 3
    cmds = {k1: (0.8, 80.0), k2: (0.0, 80.0)}
    cur, volt, _ = _stepper_means(t, cmds, (0.4, 50.0))
    trace = InputTrace.pwm_commands([0.0, t[k1], t[k2]], [0.4, 0.8, 0.0], [50.0, 80.0, 80.0])
    ref = simulate_trace_batch(P, trace, t, sampling='interval_mean')
    np.testing.assert_allclose(cur, ref.coil_current_a[0], rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(volt, ref.coil_voltage_v[0], rtol=0.0, atol=1e-6)


def test_sampling_twice_at_one_instant_returns_the_same_means() -> None:
    s = ValveStepper(P, duty=0.5, pwm_frequency_hz=50.0)
    first = s.sample()
    # no interval yet: the instantaneous values
    assert first.coil_current_mean_a == first.coil_current_a == 0.0
    assert first.coil_voltage_mean_v == first.coil_voltage_v
    s.advance_to(0.004)
    a = s.sample()
    b = s.sample()
    assert a == b
    assert s.interval_means() == (a.coil_current_mean_a, a.coil_voltage_mean_v)
    # 4 ms of supply voltage from t = 0 (high phase 10 ms): the voltage mean is 24 V
    assert a.coil_voltage_mean_v == pytest.approx(24.0, abs=1e-9)
    assert 0.0 < a.coil_current_mean_a < a.coil_current_a
    s.advance_to(0.005)
    c = s.sample()
    assert c.coil_current_mean_a != a.coil_current_mean_a
    s.reset()
    assert s.sample().coil_current_mean_a == 0.0


def test_means_are_nan_where_no_source_gives_them() -> None:
    from valve_model_pkg.model import ValveSample
    smp = ValveSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 50.0, 0.0, 0.0)
    assert math.isnan(smp.coil_current_mean_a) and math.isnan(smp.coil_voltage_mean_v)
