"""Moving average of the spool position over each PWM period (paper Section 5, x_bar).

The suite's definition (one for the whole suite)
-----------------------------------------------
The per-period moving average of the spool position at time t is **the mean position over
the last complete main PWM period** that ended at or before t, and 0 before the first
period ends. It is held constant inside a period and changes only at period ends. This is
what the simulator node and the CAN emulator publish (``ValveState.spool_position_avg``,
from :class:`~valve_model_pkg.model.ValveStepper`, whose kernel integrates it exactly),
what ``valve_simulate`` writes (``mass_flow`` from it), and what the duty maps are built
from. Its implementations:

* :func:`last_period_mean` - offline, on a sampled trace: **the definition**;
* :class:`PeriodAverager` - streaming, sample by sample: the same values;
* :func:`period_averages` - the per-period means themselves (one value per period).

:func:`moving_average` is a different quantity, a *trailing* window of one period ending
at each sample (it moves continuously); it is kept for analyses that want it (paper Fig. 7
settling) and is not the suite's moving average.
"""
from __future__ import annotations

import numpy as np

__all__ = ['hold_period_means', 'last_period_mean', 'moving_average', 'period_averages',
           'PeriodAverager']


def _cumulative_integral(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    c = np.zeros_like(x, dtype=float)
    c[1:] = np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))  # trapezoid
    return c


def moving_average(t_s: np.ndarray, x: np.ndarray, period_s: float) -> np.ndarray:
    """Trailing moving average of ``x`` over a window of one PWM period.

    Not the suite's per-period moving average (that is :func:`last_period_mean`): this
    window ends at each sample and moves continuously.

    Parameters
    ----------
    t_s : numpy.ndarray, shape (n,)
        Strictly increasing sample times, s.
    x : numpy.ndarray, shape (n,)
        Signal (e.g. spool position in m), linear between samples.
    period_s : float
        Window length, s (1 / PWM frequency).

    Returns
    -------
    numpy.ndarray, shape (n,)
        (1/T) * integral of x over [t - T, t]; before one full window has passed, the
        average over [t_0, t] (the first sample itself where t = t_0).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.shape != x.shape or t.ndim != 1:
        raise ValueError(f't_s and x must be 1-D of equal shape, got {t.shape}, {x.shape}')
    if period_s <= 0.0:
        raise ValueError(f'period_s must be positive, got {period_s!r}')
    c = _cumulative_integral(t, x)
    t_lo = np.maximum(t - period_s, t[0])
    c_lo = np.interp(t_lo, t, c)
    # the interpolated cumulative integral must use x linear inside the sample interval
    idx = np.clip(np.searchsorted(t, t_lo, side='right') - 1, 0, len(t) - 2)
    if len(t) > 1:
        frac = (t_lo - t[idx]) / (t[idx + 1] - t[idx])
        x_lo = x[idx] + frac * (x[idx + 1] - x[idx])
        c_lo = c[idx] + 0.5 * (x[idx] + x_lo) * (t_lo - t[idx])
    width = t - t_lo
    out = np.empty_like(x)
    pos = width > 0.0
    out[pos] = (c[pos] - c_lo[pos]) / width[pos]
    out[~pos] = x[~pos]
    return out


def period_averages(t_s: np.ndarray, x: np.ndarray, period_s: float,
                    t0_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Average of ``x`` over each complete period [t0 + kT, t0 + (k+1)T] inside the trace.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Period end times (s) and the averages, one per complete period.
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x, dtype=float)
    if period_s <= 0.0:
        raise ValueError(f'period_s must be positive, got {period_s!r}')
    c = _cumulative_integral(t, x)
    k0 = int(np.ceil((t[0] - t0_s) / period_s - 1e-9))
    k1 = int(np.floor((t[-1] - t0_s) / period_s + 1e-9))
    starts = t0_s + period_s * np.arange(k0, k1)
    ends = starts + period_s
    if len(starts) == 0:
        return np.zeros(0), np.zeros(0)

    def cum(tq: np.ndarray) -> np.ndarray:
        idx = np.clip(np.searchsorted(t, tq, side='right') - 1, 0, len(t) - 2)
        frac = np.clip((tq - t[idx]) / (t[idx + 1] - t[idx]), 0.0, 1.0)
        xq = x[idx] + frac * (x[idx + 1] - x[idx])
        return c[idx] + 0.5 * (x[idx] + xq) * (tq - t[idx])

    return ends, (cum(ends) - cum(starts)) / period_s


def last_period_mean(t_s: np.ndarray, x: np.ndarray, period_s: float,
                     t0_s: float = 0.0) -> np.ndarray:
    """The suite's per-period moving average of ``x`` at every sample (the definition).

    The mean of ``x`` over the last complete period [t0 + kT, t0 + (k+1)T] ending at or
    before each sample time (within 1e-9 T), 0 before the first period ends: what the
    simulator node publishes as ``spool_position_avg`` and :class:`PeriodAverager` gives
    sample by sample.

    Parameters
    ----------
    t_s : numpy.ndarray, shape (n,)
        Sample times, s, increasing.
    x : numpy.ndarray, shape (n,)
        Signal (spool position in m), linear between samples.
    period_s : float
        Main PWM period, s (1 / PWM frequency).
    t0_s : float
        Start of the first period (the first rising edge), s.

    Returns
    -------
    numpy.ndarray, shape (n,)
        Held per-period means (:func:`period_averages`), 0 before the first period ends.
    """
    t = np.asarray(t_s, dtype=float)
    ends, means = period_averages(t, x, period_s, t0_s)
    return hold_period_means(t, ends, means, period_s)


def hold_period_means(t_s: np.ndarray, period_end_s: np.ndarray, means: np.ndarray,
                      period_s: float) -> np.ndarray:
    """Per-period means held from each period end on (0 before the first end).

    Parameters
    ----------
    t_s : numpy.ndarray, shape (n,)
        Times at which to read the held value, s.
    period_end_s, means : numpy.ndarray, shape (k,)
        End time of each complete period, s (increasing), and its mean.
    period_s : float
        Period, s (an end counts as reached within 1e-9 of it).

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    t = np.asarray(t_s, dtype=float)
    out = np.zeros_like(t)
    if len(period_end_s):
        k = np.searchsorted(period_end_s, t + 1e-9 * period_s, side='right') - 1
        done = k >= 0
        out[done] = np.asarray(means)[k[done]]
    return out


class PeriodAverager:
    """Streaming average over fixed PWM periods (trapezoid on the incoming samples).

    The streaming form of the suite's moving average (:func:`last_period_mean`).

    Push samples with :meth:`update`; :attr:`value` is the average over the last complete
    period (``initial`` before the first one completes). Periods start at ``t0_s`` and
    change length only at a period boundary (:meth:`set_period`), as the valve applies a
    new PWM command.
    """

    def __init__(self, period_s: float, t0_s: float = 0.0, initial: float = 0.0) -> None:
        if period_s <= 0.0:
            raise ValueError(f'period_s must be positive, got {period_s!r}')
        self._period = float(period_s)
        self._pending = float(period_s)
        self._start = float(t0_s)
        self._acc = 0.0
        self._last: tuple[float, float] | None = None
        self.value = float(initial)
        self.completed = 0

    def set_period(self, period_s: float) -> None:
        """Use ``period_s`` from the next period boundary on."""
        if period_s <= 0.0:
            raise ValueError(f'period_s must be positive, got {period_s!r}')
        self._pending = float(period_s)

    def update(self, t_s: float, x: float) -> float:
        """Add the sample (t_s, x); returns the current :attr:`value`."""
        t_s = float(t_s)
        x = float(x)
        if self._last is None:
            self._last = (t_s, x)
            return self.value
        t_a, x_a = self._last
        if t_s <= t_a:
            raise ValueError(f'samples must be strictly increasing in time, got {t_s} '
                             f'after {t_a}')
        while True:
            end = self._start + self._period
            # a period counts as complete within 1e-9 T of its end, as in the definition
            # (:func:`last_period_mean`): sample times summed from a step miss it by an ulp
            if t_s < end - 1e-9 * self._period:
                break
            # split the sample interval at the boundary
            x_end = x_a + (x - x_a) * (end - t_a) / (t_s - t_a)
            if end > t_a:
                self._acc += 0.5 * (x_a + x_end) * (end - t_a)
            self.value = self._acc / self._period
            self.completed += 1
            self._acc = 0.0
            self._start = end
            self._period = self._pending
            t_a, x_a = max(end, t_a), x_end
        self._acc += 0.5 * (x_a + x) * (t_s - t_a)
        self._last = (t_s, x)
        return self.value
