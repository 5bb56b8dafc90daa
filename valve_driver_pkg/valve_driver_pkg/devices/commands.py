"""The host's command to a device: clamping, rejection, the watchdog, when a frame is due.

:class:`CommandState` holds what the host wants (duty, PWM frequency, enable) for the
device protocols. Its rules are the suite driver's
(:class:`~valve_driver_pkg.driver.transmit.TransmitScheduler`): NaN/inf and a negative
frequency are rejected (the last valid command stays), a duty outside [0, 1] and a
frequency outside the suite's limits are clamped; both are counted. No duty command for
``command_timeout_s`` commands duty 0 (watchdog) until the next one. Every attribute
changes under the core's lock.
"""
from __future__ import annotations

import logging
import math
import threading
import time

from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Tally
from valve_driver_pkg.driver.transmit import CommandResult
from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ

__all__ = ['CommandState']

logger = logging.getLogger(__name__)


class CommandState:
    """Duty, frequency, enable; the watchdog; the "frame due" rule.

    Parameters
    ----------
    config : DriverConfig
    lock : threading.Condition
        The core's lock (and the I/O thread's wake-up).
    tally : Tally
        Counters ``commands_received``, ``commands_rejected``, ``commands_clamped``,
        ``command_frames_sent``, ``watchdog_trips``, ``commands_lost``.
    """

    def __init__(self, config: DriverConfig, lock: threading.Condition, tally: Tally) -> None:
        self._config = config
        self._lock = lock
        self._tally = tally
        self._f_max = min(config.max_pwm_frequency_hz, MAX_PWM_FREQUENCY_HZ)
        self.active = False
        self.duty = 0.0
        self.pwm_hz = min(max(config.pwm_frequency_hz, MIN_PWM_FREQUENCY_HZ), self._f_max)
        self.supply_pa = float(config.supply_pressure_pa)
        self.output_pa = float(config.output_pressure_pa)
        self.watchdog_tripped = False
        self.disable_pending = False
        self.last_note = ''
        self.last_sent_duty = 0.0
        self._dirty = False
        self._last_command_mono: float | None = None
        self._sequences: dict[str, int] = {}

    @property
    def command(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` in force (0 while the watchdog holds)."""
        with self._lock:
            return (0.0 if self.watchdog_tripped else self.duty), self.pwm_hz

    @property
    def sent(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` of the last command frame sent. Lock held."""
        return self.last_sent_duty, self.pwm_hz

    def activate(self) -> None:
        """Start commanding at duty 0. Lock held."""
        self.duty = 0.0
        self._last_command_mono = None
        self.watchdog_tripped = False
        self.disable_pending = False
        self.active = True
        self._dirty = True

    def deactivate(self) -> bool:
        """Ask for one duty-0 disabled frame; False if not active. Lock held."""
        if not self.active:
            return False
        self.active = False
        self.duty = 0.0
        self.disable_pending = True
        return True

    def urgent(self) -> bool:
        """A frame must go out now. Lock held."""
        return self.disable_pending or (self.active and self._dirty)

    def set_command(self, duty: float, pwm_frequency_hz: float = 0.0, age_s: float = 0.0,
                    sequence: int | None = None, source: str = '') -> CommandResult:
        """Take a duty command (DutyCommand semantics); never raises.

        Parameters
        ----------
        duty, pwm_frequency_hz : float
            [1], [Hz]; frequency 0 keeps the one in force.
        age_s : float
            Unused by the device protocols (kept for the node's one call).
        sequence : int | None
            Sequence number; gaps per ``source`` are counted as ``commands_lost``.
        source : str
            The publisher the sequence numbers belong to.
        """
        duty, freq = float(duty), float(pwm_frequency_hz)
        with self._lock:
            self._tally.count('commands_received')
            if sequence is not None:
                last = self._sequences.get(source)
                self._sequences[source] = int(sequence)
                if last is not None and sequence > last + 1:
                    self._tally.count('commands_lost', int(sequence) - last - 1)
            if not (math.isfinite(duty) and math.isfinite(freq)) or freq < 0.0:
                self._tally.count('commands_rejected')
                self._tally.mark('command_rejected', time.monotonic())
                self.last_note = (f'duty command rejected: duty={duty!r}, pwm_frequency='
                                  f'{freq!r} (not finite or negative frequency); keeping the '
                                  'last valid command')
                return CommandResult(False, self.duty, self.pwm_hz, False, self.last_note)
            notes = []
            if freq == 0.0:
                freq = self.pwm_hz
            elif not MIN_PWM_FREQUENCY_HZ <= freq <= self._f_max:
                clamped = min(max(freq, MIN_PWM_FREQUENCY_HZ), self._f_max)
                notes.append(f'pwm_frequency {freq!r} Hz outside [{MIN_PWM_FREQUENCY_HZ:g}, '
                             f'{self._f_max:g}] clamped to {clamped:g}')
                freq = clamped
            if not 0.0 <= duty <= 1.0:
                clamped = min(max(duty, 0.0), 1.0)
                notes.append(f'duty {duty!r} outside [0, 1] clamped to {clamped:g}')
                duty = clamped
            if notes:
                self._tally.count('commands_clamped')
                self._tally.mark('command_clamped', time.monotonic())
                self.last_note = '; '.join(notes)
            if self.watchdog_tripped:
                logger.info('duty commands are back; watchdog released')
            self.duty, self.pwm_hz = duty, freq
            self._last_command_mono = time.monotonic()
            self.watchdog_tripped = False
            self._dirty = True
            self._lock.notify_all()
            return CommandResult(True, duty, freq, bool(notes), '; '.join(notes))

    def set_pressures(self, supply_pa: float | None, output_pa: float | None) -> bool:
        """Gauge port pressures for the derived mass flow; a non-finite value: False."""
        with self._lock:
            if any(v is not None and not math.isfinite(v) for v in (supply_pa, output_pa)):
                return False
            if supply_pa is not None:
                self.supply_pa = float(supply_pa)
            if output_pa is not None:
                self.output_pa = float(output_pa)
            return True

    def check_watchdog(self, now: float) -> bool:
        """Trip the watchdog if commands stopped; True if it tripped now."""
        limit = self._config.command_timeout_s
        with self._lock:
            if not (self.active and limit > 0.0 and not self.watchdog_tripped
                    and self._last_command_mono is not None
                    and now - self._last_command_mono > limit):
                return False
            self.watchdog_tripped = True
            self._dirty = True
            self._tally.count('watchdog_trips')
        logger.warning('watchdog: no duty command for %.3f s; valve commanded closed', limit)
        return True

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
