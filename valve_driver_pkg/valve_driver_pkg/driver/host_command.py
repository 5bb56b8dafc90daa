"""The host's command to the valve, whatever the protocol: its rules and its watchdog.

:class:`HostCommand` holds what the host wants (active, duty, PWM frequency, port
pressures) and applies the suite's rules to every duty command (DutyCommand semantics):
a non-finite value or a negative frequency is rejected (the last valid command stays),
a duty outside [0, 1] and a frequency outside the protocol's limits are clamped,
frequency 0 keeps the one in force; all are counted and the last problem kept as a note.
Gaps in the commands' sequence numbers, per source, are ``commands_lost``. No duty
command for ``command_timeout_s`` trips the watchdog: duty 0 until the next command.
The watchdog counts wall time, or the time of :attr:`HostCommand.watchdog_clock` where one
is given (a node on simulation time gives its ROS clock: a held simulation sends no
commands because no time passes, which is no silence).

The suite's protocol (:class:`~valve_driver_pkg.driver.transmit.TransmitScheduler`) and
the device protocols (:class:`~valve_driver_pkg.devices.commands.CommandState`) extend it
with when their frames are due. Every attribute changes under the driver core's one lock.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Tally

__all__ = ['HostCommand', 'CommandResult']

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class CommandResult:
    """What ``set_command`` did with a duty command."""

    accepted: bool
    duty: float
    pwm_frequency_hz: float
    clamped: bool
    message: str


class HostCommand:
    """The host's command and its rules (module docstring).

    Parameters
    ----------
    config : DriverConfig
    lock : threading.Condition
        The driver core's lock (and the I/O thread's wake-up).
    tally : Tally
        Counters ``commands_received``, ``commands_rejected``, ``commands_clamped``,
        ``commands_lost``, ``commands_out_of_order``, ``watchdog_trips``.
    f_min, f_max : float
        The PWM frequencies the protocol can carry [Hz].
    """

    def __init__(self, config: DriverConfig, lock: threading.Condition, tally: Tally,
                 f_min: float, f_max: float) -> None:
        self._config = config
        self._lock = lock
        self._tally = tally
        self._f_min, self._f_max = f_min, f_max
        self.active = False
        self.duty = 0.0
        self.pwm_hz = min(max(config.pwm_frequency_hz, f_min), f_max)
        self.supply_pa = float(config.supply_pressure_pa)
        self.output_pa = float(config.output_pressure_pa)
        self.watchdog_tripped = False
        self.disable_pending = False     # deactivate(): one "disable" frame still to send
        self.last_command_note = ''
        self._last_command_t: float | None = None   # on the watchdog's clock [s]
        self._sequences: dict[str, int] = {}
        #: The watchdog's time base [s]; None = the wall clock (monotonic).
        self.watchdog_clock: Callable[[], float] | None = None

    # --- what the subclasses add -------------------------------------------------------------
    def _command_changed(self) -> None:
        """The command frame must go out at once. Lock held."""

    def _accepted(self, now: float, age_s: float) -> None:
        """A valid command of age ``age_s`` was taken at ``now``. Lock held."""

    def _pressures_changed(self) -> None:
        """The pressures changed. Lock held."""

    def _activated(self) -> None:
        """The command starts (again). Lock held."""

    def _deactivated(self) -> None:
        """The command stops. Lock held."""

    # --- the caller's side (any thread) ------------------------------------------------------
    @property
    def command(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` in force (0 while the watchdog holds)."""
        with self._lock:
            return (0.0 if self.watchdog_tripped else self.duty), self.pwm_hz

    def activate(self) -> None:
        """Start commanding; duty 0 until a command arrives. Lock held."""
        self.duty = 0.0
        self._last_command_t = None
        self.watchdog_tripped = False
        self.disable_pending = False
        self.active = True
        self._activated()
        self._lock.notify_all()

    def deactivate(self) -> bool:
        """Ask for one duty-0 frame with the output disabled, then silence. Lock held.

        Returns
        -------
        bool
            False if it was not active (nothing to send).
        """
        if not self.active:
            return False
        self.active = False
        self.duty = 0.0
        self._deactivated()
        self.disable_pending = True
        self._lock.notify_all()
        return True

    def set_command(self, duty: float, pwm_frequency_hz: float = 0.0, age_s: float = 0.0,
                    sequence: int | None = None, source: str = '') -> CommandResult:
        """Take a duty command (DutyCommand semantics); never raises, never sends raw.

        Parameters
        ----------
        duty, pwm_frequency_hz : float
            The command ([1], [Hz]); frequency 0 keeps the one in force.
        age_s : float
            How old the command already is on arrival (now minus its header stamp) [s].
        sequence : int | None
            The command's sequence number; gaps per ``source`` are counted as lost.
        source : str
            The publisher the sequence numbers belong to.
        """
        duty, freq = float(duty), float(pwm_frequency_hz)
        with self._lock:
            now = time.monotonic()
            self._tally.count('commands_received')
            if sequence is not None:
                self._check_sequence(int(sequence), source)
            if not (math.isfinite(duty) and math.isfinite(freq)) or freq < 0.0:
                self._tally.count('commands_rejected')
                self._tally.mark('command_rejected', now)
                note = (f'duty command rejected: duty={duty!r}, pwm_frequency={freq!r} '
                        '(not finite or negative frequency); keeping the last valid command')
                self.last_command_note = note
                return CommandResult(False, self.duty, self.pwm_hz, False, note)
            duty, freq, notes = self._clamp(duty, freq)
            if notes:
                self._tally.count('commands_clamped')
                self._tally.mark('command_clamped', now)
                self.last_command_note = '; '.join(notes)
            self.duty, self.pwm_hz = duty, freq
            self._last_command_t = now if self.watchdog_clock is None else self.watchdog_clock()
            self._accepted(now, float(age_s) if math.isfinite(age_s) and 0.0 <= age_s < 3600.0
                           else 0.0)
            if self.watchdog_tripped:
                logger.info('duty commands are back; watchdog released')
            self.watchdog_tripped = False
            self._command_changed()
            self._lock.notify_all()
            return CommandResult(True, duty, freq, bool(notes), '; '.join(notes))

    def _clamp(self, duty: float, freq: float) -> tuple[float, float, list[str]]:
        """Duty into [0, 1], frequency into the protocol's limits (0: the one in force)."""
        notes = []
        if freq == 0.0:
            freq = self.pwm_hz
        elif not self._f_min <= freq <= self._f_max:
            clamped = min(max(freq, self._f_min), self._f_max)
            notes.append(f'pwm_frequency {freq!r} Hz outside [{self._f_min:g}, '
                         f'{self._f_max:g}] clamped to {clamped:g}')
            freq = clamped
        if not 0.0 <= duty <= 1.0:
            clamped = min(max(duty, 0.0), 1.0)
            notes.append(f'duty {duty!r} outside [0, 1] clamped to {clamped:g}')
            duty = clamped
        return duty, freq, notes

    def _check_sequence(self, sequence: int, source: str) -> None:
        """Count the sequence numbers missing since the last command of ``source``."""
        last = self._sequences.get(source)
        self._sequences[source] = sequence
        if last is None:
            return
        if sequence > last + 1:
            self._tally.count('commands_lost', sequence - last - 1)
            self._tally.mark('command_lost', time.monotonic())
        elif sequence <= last:
            self._tally.count('commands_out_of_order')   # a restarted publisher, or reordering

    def set_pressures(self, supply_pa: float | None = None,
                      output_pa: float | None = None) -> bool:
        """Set the port pressures (gauge Pa); a non-finite value is rejected (False)."""
        with self._lock:
            if any(v is not None and not math.isfinite(v) for v in (supply_pa, output_pa)):
                return False
            if supply_pa is not None:
                self.supply_pa = float(supply_pa)
            if output_pa is not None:
                self.output_pa = float(output_pa)
            self._pressures_changed()
            self._lock.notify_all()
            return True

    # --- I/O thread --------------------------------------------------------------------------
    def check_watchdog(self, now: float) -> bool:
        """Trip the duty watchdog if commands stopped; True if it tripped now.

        ``now`` is the wall clock (monotonic) [s]; with a :attr:`watchdog_clock` its time
        counts instead.
        """
        limit = self._config.command_timeout_s
        with self._lock:
            if self.watchdog_clock is not None:
                now = self.watchdog_clock()
            if not (self.active and limit > 0.0 and not self.watchdog_tripped
                    and self._last_command_t is not None
                    and now - self._last_command_t > limit):
                return False
            self.watchdog_tripped = True
            self._tally.count('watchdog_trips')
            self._command_changed()
        logger.warning('watchdog: no duty command for %.3f s; valve commanded closed', limit)
        return True
