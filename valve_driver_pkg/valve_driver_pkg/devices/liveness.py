"""Is the device alive? Silence for :data:`LIVENESS_PERIODS` of its own periods says no.

:class:`DeviceLiveness` follows the frames a device sends (heartbeat, Estimated Flow, the
board's status: any frame from it) and declares it lost once it has been silent for
``LIVENESS_PERIODS`` x its period, counted from its last frame or, before the first, from
the moment the bus opened. The next frame from it brings it back. Not thread-safe: the
core calls it under its lock.
"""
from __future__ import annotations

import math

from valve_driver_pkg.devices.base import LIVENESS_PERIODS

__all__ = ['DeviceLiveness']


class DeviceLiveness:
    """The device's liveness (module docstring).

    Parameters
    ----------
    period_s : float
        The device's own cyclic period [s]; ``inf``: it sends nothing cyclic (never lost).
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lost = False
        self.lost_after_s = 0.0
        self.last_mono: float | None = None
        self._since_mono = 0.0

    @property
    def limit_s(self) -> float:
        """The silence that makes the device lost [s]."""
        return LIVENESS_PERIODS * self.period_s

    def start(self, now: float) -> None:
        """The bus opened at ``now``: the silence counts from here until a first frame."""
        self._since_mono = now
        self.last_mono = None
        self.lost = False

    def heard(self, now: float) -> bool:
        """A frame from the device at ``now``; True if that brings a lost device back."""
        self.last_mono = now
        back, self.lost = self.lost, False
        return back

    def age_s(self, now: float) -> float:
        """How long the device has been silent [s] (``inf`` before its first frame)."""
        return math.inf if self.last_mono is None else now - self.last_mono

    def deadline(self, watching: bool) -> float:
        """The monotonic time the device is lost if still silent (``inf``: not judged now;
        ``watching`` False while it is not set up)."""
        if self.lost or not watching or not math.isfinite(self.period_s):
            return math.inf
        ref = self.last_mono if self.last_mono is not None else self._since_mono
        return ref + self.limit_s + 1e-4

    def check(self, now: float, watching: bool) -> bool:
        """Declare the device lost if its deadline has passed; True if it was just lost."""
        if now < self.deadline(watching):
            return False
        ref = self.last_mono if self.last_mono is not None else self._since_mono
        self.lost = True
        self.lost_after_s = now - ref
        return True
