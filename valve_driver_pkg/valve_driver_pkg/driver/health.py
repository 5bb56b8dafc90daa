"""Telemetry health: loss judged on evidence (counter gaps, silence), with hysteresis.

A late frame is not a lost frame. On a loaded machine the driver's receive thread may run
tens of milliseconds late and then read a burst of queued frames whose rolling counters are
continuous: nothing was lost, and nothing is reported. :class:`TelemetryHealth` declares
the telemetry lost (ERROR) only on evidence that frames are missing:

* **silence**: no valid frame for ``silence_s`` (``DriverConfig.telemetry_timeout_s``:
  50 telemetry periods or 100 ms, whichever is longer), or
* **counter gaps**: ``error_windows`` consecutive windows of ``window_s`` in each of which at
  least ``loss_fraction`` of the frames the counters account for are missing.

It leaves the ERROR after ``ok_windows`` consecutive good windows (frames received, gaps
below the fraction) and no silence. A window with no frame at all is no evidence either
way (the silence rule covers it). The class keeps no clock: every call passes ``now`` (a
monotonic time in seconds), so tests drive it in simulated time. Not thread-safe by
itself; the driver core calls it under its lock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['TelemetryHealth', 'HealthChange']

#: Above this many telemetry periods between two frames the 4-bit counter may have wrapped:
#: its gap then says nothing about how many frames were lost.
_COUNTER_TRUST_PERIODS = 8


@dataclass(frozen=True, slots=True)
class HealthChange:
    """A transition of :class:`TelemetryHealth` (None when nothing changed)."""

    lost: bool
    reason: str          # 'silence', 'counter gaps' or 'recovered'
    after_s: float       # silence: time since the last frame; gaps: the bad run's length


class TelemetryHealth:
    """Loss detection of one telemetry stream (see the module docstring).

    Parameters
    ----------
    period_s : float
        Expected telemetry period [s].
    silence_s : float
        No frame for longer than this is a loss [s].
    window_s : float
        Length of the judging windows [s].
    loss_fraction : float
        A window is bad when ``lost >= loss_fraction * (lost + received)`` and ``lost > 0``.
    error_windows, ok_windows : int
        Consecutive bad windows that enter, and good windows that leave, the lost state.
    """

    def __init__(self, period_s: float, silence_s: float, window_s: float,
                 loss_fraction: float, error_windows: int, ok_windows: int) -> None:
        self.period_s = period_s
        self.silence_s = silence_s
        self.window_s = window_s
        self.loss_fraction = loss_fraction
        self.error_windows = error_windows
        self.ok_windows = ok_windows
        self.lost = False
        self.reason = ''
        self.lost_after_s = 0.0
        self.last_frame: float | None = None
        self.bad_windows = 0          # windows judged bad since the start (a counter)
        self._reference = 0.0         # silence is measured from here before the first frame
        self._window_end = math.inf
        self._received = 0
        self._missing = 0
        self._bad_run = 0
        self._good_run = 0

    def reset(self, now: float) -> None:
        """A bus was (re)opened at ``now``: windows and the silence timer start afresh."""
        self.last_frame = None
        self._reference = now
        self._window_end = now + self.window_s
        self._received = self._missing = 0
        self._bad_run = self._good_run = 0

    def frame(self, now: float, missing: int) -> None:
        """A valid frame arrived at ``now``; its counter says ``missing`` frames before it."""
        last = self.last_frame
        if last is not None and now - last > _COUNTER_TRUST_PERIODS * self.period_s:
            missing = 0   # the counter may have wrapped; the silence rule judges this gap
        self._received += 1
        self._missing += missing
        self.last_frame = now

    def silence(self, now: float) -> float:
        """Time since the last frame (or the reset, before the first) [s]."""
        return now - (self.last_frame if self.last_frame is not None else self._reference)

    def deadline(self) -> float:
        """The next instant :meth:`update` may change the state (window end or silence)."""
        silent_at = (self.last_frame if self.last_frame is not None
                     else self._reference) + self.silence_s
        return min(self._window_end, math.inf if self.lost else silent_at)

    def update(self, now: float) -> HealthChange | None:
        """Close the windows that ended by ``now``, apply the rules; the change, if any."""
        change = None
        while now >= self._window_end:
            change = self._close_window() or change
        silent = self.silence(now)
        if not self.lost and silent > self.silence_s:
            self.lost, self.reason, self.lost_after_s = True, 'silence', silent
            self._good_run = 0
            change = HealthChange(True, 'silence', silent)
        return change

    def _close_window(self) -> HealthChange | None:
        received, missing = self._received, self._missing
        self._received = self._missing = 0
        self._window_end += self.window_s
        bad = missing > 0 and missing >= self.loss_fraction * (received + missing)
        if bad:
            self.bad_windows += 1
            self._bad_run += 1
            self._good_run = 0
        elif received > 0:
            self._good_run += 1
            self._bad_run = 0
        else:
            self._good_run = 0   # an empty window is no evidence of health
        if not self.lost and self._bad_run >= self.error_windows:
            self.lost, self.reason = True, 'counter gaps'
            self.lost_after_s = self._bad_run * self.window_s
            return HealthChange(True, 'counter gaps', self.lost_after_s)
        if self.lost and self._good_run >= self.ok_windows:
            self.lost, self.reason = False, ''
            self._bad_run = 0
            return HealthChange(False, 'recovered', self._good_run * self.window_s)
        return None
