"""Streaming moving average of the spool position over one PWM period (ROS-free)."""
from __future__ import annotations

import collections

__all__ = ['PeriodAverager']


class PeriodAverager:
    """Trapezoidal moving average of a sampled signal over the last ``window_s`` seconds.

    The paper's x_bar is the spool position averaged over one main PWM period; the
    controller sends the position every telemetry period, so the driver integrates the
    samples (trapezoid rule) over a sliding window of one PWM period. In steady state the
    sliding average equals the period average whatever the phase; with samples ``dt`` apart
    the integral of a fast edge is off by at most about ``dt/2`` times the stroke per edge.

    Parameters
    ----------
    window_s : float
        Window length [s] (one PWM period, ``1 / f_pwm``).
    """

    def __init__(self, window_s: float) -> None:
        self._segments: collections.deque[tuple[float, float, float]] = collections.deque()
        self._area = 0.0
        self._last: tuple[float, float] | None = None
        self.window_s = float(window_s)

    def set_window(self, window_s: float) -> None:
        """Change the window (a new PWM frequency); old samples stay and are trimmed."""
        self.window_s = float(window_s)

    def reset(self) -> None:
        """Forget all samples (after a gap in the telemetry)."""
        self._segments.clear()
        self._area = 0.0
        self._last = None

    def add(self, t_s: float, value: float) -> float:
        """Add the sample ``value`` at time ``t_s`` (increasing); return the average.

        Until a sample pair exists the average is the sample itself; until a whole window
        is covered it is the average over the time covered so far.
        """
        last = self._last
        self._last = (t_s, value)
        if last is None or t_s <= last[0]:
            if last is None:
                return value
            return self.average()
        t0, v0 = last
        area = 0.5 * (v0 + value) * (t_s - t0)
        self._segments.append((t0, t_s, area))
        self._area += area
        start = t_s - self.window_s
        segments = self._segments
        while segments and segments[0][1] <= start:
            self._area -= segments.popleft()[2]
        if not segments:
            self._area = 0.0
        return self.average()

    def average(self) -> float:
        """Average over the window (partial first segment interpolated)."""
        segments = self._segments
        if not segments:
            return self._last[1] if self._last else 0.0
        t_end = segments[-1][1]
        start = t_end - self.window_s
        first_t0, first_t1, first_area = segments[0]
        area = self._area
        covered_start = first_t0
        if first_t0 < start:
            # Keep only the part of the first segment inside the window (linear share).
            area -= first_area * (start - first_t0) / (first_t1 - first_t0)
            covered_start = start
        covered = t_end - covered_start
        return area / covered if covered > 0.0 else self._last[1]
