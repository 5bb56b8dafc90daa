"""The host's command to a device: when its frame is due.

:class:`CommandState` is the suite's :class:`~valve_driver_pkg.driver.host_command.HostCommand`
(rejection, clamping, the watchdog, lost sequence numbers) for the device protocols, plus
the rule for their command frames: at once on a change, then every command period (the
core keeps the period), and one duty-0 frame with the output disabled on deactivate.
Every attribute changes under the core's lock.
"""
from __future__ import annotations

import threading

from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Tally
from valve_driver_pkg.driver.host_command import HostCommand
from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ

__all__ = ['CommandState']


class CommandState(HostCommand):
    """Duty, frequency, enable; the watchdog; the "frame due" rule.

    Parameters
    ----------
    config : DriverConfig
    lock : threading.Condition
        The core's lock (and the I/O thread's wake-up).
    tally : Tally
        Counters of :class:`HostCommand` and ``command_frames_sent``.
    """

    def __init__(self, config: DriverConfig, lock: threading.Condition, tally: Tally) -> None:
        super().__init__(config, lock, tally, MIN_PWM_FREQUENCY_HZ,
                         min(config.max_pwm_frequency_hz, MAX_PWM_FREQUENCY_HZ))
        self.last_sent_duty = 0.0
        self._dirty = False

    @property
    def sent(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` of the last command frame sent. Lock held."""
        return self.last_sent_duty, self.pwm_hz

    def _command_changed(self) -> None:
        self._dirty = True

    def _activated(self) -> None:
        self._dirty = True

    def urgent(self) -> bool:
        """A frame must go out now. Lock held."""
        return self.disable_pending or (self.active and self._dirty)

    def due(self, now: float, next_t: float) -> tuple[float, bool, bool] | None:
        """``(duty, enable, disabling)`` if a command frame is due now, else None. Lock held."""
        if self.disable_pending:
            return 0.0, False, True
        if not self.active or not (self._dirty or now >= next_t):
            return None
        self._dirty = False
        return (0.0 if self.watchdog_tripped else self.duty), True, False

    def sent_frame(self, duty: float, sent: bool, disabling: bool) -> None:
        """The frames of a command went out (``sent``) or failed."""
        with self._lock:
            if sent:
                self._tally.count('command_frames_sent')
                self.last_sent_duty = duty
            if disabling:
                self.disable_pending = False
                self._lock.notify_all()
