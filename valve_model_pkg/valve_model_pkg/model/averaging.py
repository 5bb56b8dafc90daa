"""Moving average of the spool position over each PWM period (paper Section 5, x_bar).

Offline from a sampled trace (:func:`moving_average`, :func:`period_averages`) and as a
streaming filter (:class:`PeriodAverager`) for live data.
"""
from __future__ import annotations

import numpy as np

__all__ = ['moving_average', 'period_averages', 'PeriodAverager']


def _cumulative_integral(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    c = np.zeros_like(x, dtype=float)
    c[1:] = np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))  # trapezoid
    return c


def moving_average(t_s: np.ndarray, x: np.ndarray, period_s: float) -> np.ndarray:
    """Trailing moving average of ``x`` over a window of one PWM period.

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


class PeriodAverager:
    """Streaming average over fixed PWM periods (trapezoid on the incoming samples).

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
            if t_s < end:
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
