"""Moving average over the PWM period: offline and streaming against analytic values."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from valve_model_pkg.model import PeriodAverager, moving_average, period_averages


def _square(t: np.ndarray, duty: float, period: float) -> np.ndarray:
    return ((t % period) < duty * period).astype(float)


def test_moving_average_of_a_square_wave_is_the_duty() -> None:
    t = np.linspace(0, 0.1, 100001)
    x = _square(t, 0.3, 0.02)
    avg = moving_average(t, x, 0.02)
    np.testing.assert_allclose(avg[t >= 0.02], 0.3, atol=2e-4)
    ends, per = period_averages(t, x, 0.02)
    np.testing.assert_allclose(ends, [0.02, 0.04, 0.06, 0.08, 0.1])
    np.testing.assert_allclose(per, 0.3, atol=2e-4)


def test_moving_average_of_a_ramp_is_exact() -> None:
    t = np.linspace(0, 1, 101)
    avg = moving_average(t, 2 * t, 0.25)
    # trailing window [t - T, t] of 2t averages to 2t - T (linear: trapezoid is exact)
    np.testing.assert_allclose(avg[t >= 0.25], 2 * t[t >= 0.25] - 0.25, atol=1e-12)
    np.testing.assert_allclose(avg[1:][t[1:] < 0.25], t[1:][t[1:] < 0.25], atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(period=st.floats(0.005, 0.05), duty=st.floats(0.0, 1.0),
       step=st.floats(1e-4, 2e-3))
# a last sample one ulp before a period's end: complete in both, within 1e-9 T
@example(period=0.005, duty=0.0, step=0.0019999999999999996)
def test_streaming_filter_equals_offline(period: float, duty: float, step: float) -> None:
    t = np.arange(0, 0.2, step)
    x = np.sin(40 * t) + duty
    ends, ref = period_averages(t, x, period)
    f = PeriodAverager(period)
    values = []
    for ti, xi in zip(t, x):
        before = f.completed
        f.update(ti, xi)
        if f.completed > before:
            values.append(f.value)
    assert f.completed == len(ref)
    np.testing.assert_allclose(values, ref, rtol=1e-9, atol=1e-12)


def test_streaming_period_change_at_boundary() -> None:
    f = PeriodAverager(0.01)
    f.set_period(0.02)
    t = np.arange(0, 0.05 + 1e-12, 1e-4)
    for ti in t:
        f.update(ti, 1.0)
    assert f.completed == 3  # [0, 0.01], [0.01, 0.03], [0.03, 0.05]
    assert f.value == pytest.approx(1.0)
    with pytest.raises(ValueError, match='strictly increasing'):
        f.update(0.01, 1.0)
    with pytest.raises(ValueError, match='period_s must be positive'):
        PeriodAverager(0.0)
