"""Moving average of the spool position per PWM period (paper Section 5, Fig. 7).

Fig. 7: 50 Hz, the duty steps from 25 % to 50 %. The paper says the average position shows
"rapid transient behaviors (only in the first cycle after the step input change)". These
tests measure how many PWM periods the model's average needs to settle after the step and
check that claim, offline from a sampled trace (model.averaging) and with the streaming
filter (model.averaging.PeriodAverager, and the stepper's own per-period average that the
simulator node publishes as ``spool_position_avg``).
"""
from __future__ import annotations

import numpy as np
import pytest

from valve_model_pkg.model import (ElectronicsConfig, PeriodAverager, ValveStepper,
                                   load_parameters, moving_average, period_averages)

FREQ_HZ = 50.0
PERIOD_S = 1.0 / FREQ_HZ
STEP_PERIOD = 20          # the new duty applies from the start of period 20
AFTER = 12                # periods simulated after the step
SAMPLE_DT = 20e-6         # 50 kHz trace
SUPPLY_PA = 4.0e5         # the paper's stated experiments are at 4 bar
#: "Settled": within 1 % of the stroke of the final periodic value (a figure-level
#: tolerance: 1 % of x_max is 3.3 um, about the line width of Fig. 7).
SETTLE_TOL = 0.01


@pytest.fixture(scope='module')
def fig7() -> dict:
    params = load_parameters()
    stepper = ValveStepper(params, ElectronicsConfig(), duty=0.25, pwm_frequency_hz=FREQ_HZ,
                           supply_pressure_pa=SUPPLY_PA)
    t_step = STEP_PERIOD * PERIOD_S
    t_end = t_step + AFTER * PERIOD_S
    n = int(round(t_end / SAMPLE_DT))
    t = np.arange(1, n + 1) * SAMPLE_DT
    x = np.empty(n)
    x_avg_kernel = np.empty(n)
    commanded = False
    for k, tk in enumerate(t):
        if not commanded and tk > t_step - 0.5 * PERIOD_S:
            stepper.set_command(0.5, FREQ_HZ)   # applies at the next period start = t_step
            commanded = True
        stepper.advance_to(tk)
        s = stepper.sample()
        x[k] = s.spool_position_m
        x_avg_kernel[k] = s.position_avg_m
    return {'t': t, 'x': x, 'x_avg_kernel': x_avg_kernel, 't_step': t_step,
            'stroke': params.stroke_m}


def _settle_index(values: np.ndarray, final: float, tol: float) -> int:
    """Smallest k such that values[k:] all lie within tol of final."""
    outside = np.nonzero(np.abs(values - final) > tol)[0]
    return 0 if outside.size == 0 else int(outside[-1]) + 1


def test_period_averages_settle_within_first_period_after_step(fig7: dict) -> None:
    """The paper's claim: only the first PWM period after the step is a transient."""
    ends, avg = period_averages(fig7['t'], fig7['x'], PERIOD_S, t0_s=0.0)
    frac = avg / fig7['stroke']
    after = frac[ends > fig7['t_step'] + 1e-9]      # period 0 = the first one after the step
    before = frac[(ends <= fig7['t_step'] + 1e-9) & (ends > fig7['t_step'] - 4 * PERIOD_S)]
    assert after.size >= AFTER - 1
    final = after[-1]
    # the steps before are steady at 25 % duty and the final value is the 50 % one
    assert np.ptp(before) < 1e-3
    assert final > before[-1] + 0.1
    settle = _settle_index(after, final, SETTLE_TOL)
    print(f'Fig. 7: period averages after the step {np.round(after[:5] * 100, 2)} % '
          f'(final {final * 100:.2f} %), settled after {settle} period(s)')
    # index 0 is the first period after the step: settled from period 1 on = "only the
    # first cycle" is transient
    assert settle <= 1, f'settles after {settle} periods, not within the first one'


def test_moving_average_settling_time(fig7: dict) -> None:
    """The trailing one-period moving average (Fig. 7's curve) settles within 2 periods."""
    t, x = fig7['t'], fig7['x']
    ma = moving_average(t, x, PERIOD_S) / fig7['stroke']
    final = ma[-1]
    sel = t > fig7['t_step']
    k = _settle_index(ma[sel], final, SETTLE_TOL)
    settle_periods = (t[sel][min(k, sel.sum() - 1)] - fig7['t_step']) / PERIOD_S
    print(f'Fig. 7: the moving average settles {settle_periods:.2f} periods after the step')
    # a one-period window needs one period to forget the old duty; the spool's own
    # transient is confined to the first period, so it is steady by 2 periods
    assert 1.0 - 1e-6 <= settle_periods <= 2.0


def test_streaming_filter_matches_offline(fig7: dict) -> None:
    """PeriodAverager on the samples = offline period averages = the stepper's own value."""
    t, x = fig7['t'], fig7['x']
    ends, offline = period_averages(t, x, PERIOD_S, t0_s=0.0)
    filt = PeriodAverager(PERIOD_S, t0_s=0.0)
    streamed = {}
    for tk, xk in zip(t, x):
        before = filt.completed
        filt.update(tk, xk)
        if filt.completed > before:
            streamed[filt.completed] = filt.value
    # period k (1-based count of completed periods) ends at k T; the trace starts one
    # sample after 0, so both leave out the first sample interval alike; a period whose
    # end falls after the last sample by rounding is not streamed
    compared = 0
    for end, value in zip(ends, offline):
        k = int(round(end / PERIOD_S))
        if k in streamed and k > 1:
            assert streamed[k] == pytest.approx(value, abs=1e-4 * fig7['stroke'])
            compared += 1
    assert compared >= STEP_PERIOD + AFTER - 3
    # the stepper's exact per-period average (what the simulator node publishes), read
    # just after each period end, agrees with the sampled trace to the trapezoid error
    idx = [int(round(end / SAMPLE_DT)) for end in ends]   # sample just after the end
    kernel = fig7['x_avg_kernel'][np.minimum(idx, len(t) - 1)]
    np.testing.assert_allclose(kernel, offline, atol=2e-3 * fig7['stroke'])
