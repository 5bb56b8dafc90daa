"""The driver's transmit scheduler: duty command, port pressures, the command watchdog.

:class:`TransmitScheduler` keeps what the host wants the controller to do and decides
when ``ValveCommand`` and ``ValvePressure`` go out: at once on a change, and at their
refresh rates. Callers (the node's callbacks) only store values and wake the I/O thread;
the I/O thread calls :meth:`check_watchdog` and :meth:`send_due`. Every attribute
changes only under the driver core's one lock; frames are encoded and sent outside it.

Accounting of duty commands (nothing lost unreported): every command offered to
:meth:`set_command` is ``commands_received``; it is then rejected (``commands_rejected``),
or accepted and either reaches the bus in a ``ValveCommand`` frame (``commands_on_bus``)
or is replaced by a newer one before its frame went out (``commands_superseded``). A
command whose frame goes out more than ``stale_command_s`` after its origin (its header
stamp, else its receipt) is also counted as ``stale_commands``. Gaps in the commands'
sequence numbers, per source, are ``commands_lost`` (lost before they reached the driver).
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque

from valve_driver_pkg.driver.bus_link import BusLink
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Tally
from valve_driver_pkg.driver.host_command import CommandResult, HostCommand
from valve_driver_pkg.errors import ProtocolEncodeError
from valve_driver_pkg.protocol.codec import COMMAND, PRESSURE, DriveMode, ValveCodec
from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ

__all__ = ['CommandResult', 'TransmitScheduler']

logger = logging.getLogger(__name__)

#: While inactive the I/O thread looks again after this long [s].
_IDLE_S = 0.05
#: Own ValveCommand frames remembered to recognise their echo (an interface that loops
#: sent frames back must not make the driver see a second host).
_ECHO_MEMORY = 16


class TransmitScheduler(HostCommand):
    """Command and pressure state, and when their frames are due.

    Parameters
    ----------
    config : DriverConfig
    codec : ValveCodec
    lock : threading.Condition
        The driver core's lock (and the I/O thread's wake-up).
    tally : Tally
        Counters: ``commands_*``, ``command_frames_sent``, ``pressure_frames_sent``,
        ``watchdog_trips``, ``internal_errors`` (an encode error: a bug, never sent raw).
    """

    def __init__(self, config: DriverConfig, codec: ValveCodec, lock: threading.Condition,
                 tally: Tally) -> None:
        f_lo, f_hi = codec.signal_range(COMMAND, 'PwmFrequency')
        # The suite's one pair of limits; a custom DBC can only narrow them.
        super().__init__(config, lock, tally, max(f_lo, MIN_PWM_FREQUENCY_HZ),
                         min(f_hi, config.max_pwm_frequency_hz, MAX_PWM_FREQUENCY_HZ))
        self._codec = codec
        self.host_id = config.effective_host_id
        self._p_lo, self._p_hi = codec.signal_range(PRESSURE, 'SupplyPressure')
        self._command_period = 1.0 / config.command_rate_hz
        self._pressure_period = 1.0 / config.pressure_rate_hz
        self.drive_mode = DriveMode.parse(config.drive_mode)
        self.last_sent_duty = 0.0
        self._command_dirty = False
        self._pressure_dirty = True
        self._command_gen = 0            # +1 per change; a send clears "dirty" only if unchanged
        self._pressure_gen = 0
        self._next_command_t = 0.0
        self._next_pressure_t = 0.0
        self._tx_counter = 0
        self._pressure_counter = 0
        self.clear_pending = False       # clear_faults(): one ClearFaults=1 frame to send
        self.clear_sent_mono: float | None = None
        self._origin: float | None = None   # origin (monotonic) of the command not yet sent
        self.max_command_age_s = 0.0     # largest origin-to-bus age of a command [s]
        self.last_stale_age_s = 0.0
        self._sent = deque(maxlen=_ECHO_MEMORY)

    def sent_recently(self, data: bytes) -> bool:
        """True if ``data`` is one of the last ValveCommand frames sent. Lock held."""
        return data in self._sent

    def request_clear(self) -> None:
        """Send one ValveCommand with ``ClearFaults=1`` (also while inactive). Lock held."""
        self.clear_pending = True
        self.clear_sent_mono = None
        self._lock.notify_all()

    # --- the caller's side (any thread) ------------------------------------------------------
    def mark_dirty(self) -> None:
        """Send both frames at once (activation, a reopened bus). Lock held."""
        self._command_changed()
        self._pressures_changed()
        self._lock.notify_all()

    def _command_changed(self) -> None:
        self._command_dirty = True
        self._command_gen += 1

    def _pressures_changed(self) -> None:
        self._pressure_dirty = True
        self._pressure_gen += 1

    def _accepted(self, now: float, age_s: float) -> None:
        """Accounting: the command not yet on the bus is superseded; this one's origin."""
        if self._origin is not None:
            self._tally.count('commands_superseded')   # replaced before its frame went out
        self._origin = now - age_s

    def _activated(self) -> None:
        self._drop_pending()
        self.mark_dirty()

    def _deactivated(self) -> None:
        self._drop_pending()

    def set_drive_mode(self, mode: str | DriveMode) -> DriveMode:
        """Send ``mode`` in every ValveCommand from now on, the next frame at once.

        The mode never changes what a stop does: duty 0, ``Enable=0`` (deactivate) and the
        watchdog switch the coil off at once in either mode (docs/safety.md).

        Returns
        -------
        DriveMode
            The mode sent before.

        Raises
        ------
        ValueError
            ``mode`` is not a drive mode name (nothing changes).
        """
        new = mode if isinstance(mode, DriveMode) else DriveMode.parse(mode)
        with self._lock:
            old, self.drive_mode = self.drive_mode, new
            if new != old:
                self._command_changed()
                self._lock.notify_all()
        return old

    # --- I/O thread --------------------------------------------------------------------------
    def next_due(self) -> float:
        """Monotonic time of the next scheduled frame. Lock held."""
        return min(self._next_command_t, self._next_pressure_t)

    def urgent(self) -> bool:
        """A frame must go out now (new command, disable, new pressures). Lock held."""
        return (self._command_dirty or self.disable_pending or self.clear_pending
                or (self._pressure_dirty and self.active))

    def send_due(self, now: float, link: BusLink) -> None:
        """Send the frames that are due on ``link`` (I/O thread)."""
        with self._lock:
            disabling = self.disable_pending
            clearing = self.clear_pending
            send_command = disabling or clearing or (
                self.active and (self._command_dirty or now >= self._next_command_t))
            send_pressure = self.active and (self._pressure_dirty
                                             or now >= self._next_pressure_t)
            enable = self.active and not disabling
            duty = 0.0 if (self.watchdog_tripped or not enable) else self.duty
            freq = self.pwm_hz
            mode = int(self.drive_mode)
            supply = min(max(self.supply_pa, self._p_lo), self._p_hi)
            output = min(max(self.output_pa, self._p_lo), self._p_hi)
            command_gen, pressure_gen = self._command_gen, self._pressure_gen
            origin = self._origin if enable else None
            if not self.active and not disabling:
                self._next_command_t = self._next_pressure_t = now + _IDLE_S
        if not link.usable:
            return
        if send_command:
            sent = self._send(link, COMMAND, {'Duty': duty, 'PwmFrequency': freq,
                                              'Enable': int(enable),
                                              'ClearFaults': int(clearing),
                                              'HostId': self.host_id,
                                              'DriveMode': mode},
                              self._tx_counter)
            with self._lock:
                self._tx_counter = (self._tx_counter + 1) & 0xF
                if sent and clearing:
                    self.clear_pending = False
                    self.clear_sent_mono = time.monotonic()
                    self._lock.notify_all()
                if sent and origin is not None and self._origin == origin:
                    self._account_age(time.monotonic() - origin)
                if self._command_gen == command_gen:   # else a newer command is waiting
                    self._command_dirty = False
                self._next_command_t = now + self._command_period
                if sent:
                    self._tally.count('command_frames_sent')
                    self.last_sent_duty = duty
                if disabling:   # only the frame built as "disable" completes deactivate()
                    self.disable_pending = False
                    self._lock.notify_all()
        if send_pressure:
            sent = self._send(link, PRESSURE, {'SupplyPressure': supply,
                                               'OutputPressure': output},
                              self._pressure_counter)
            with self._lock:
                self._pressure_counter = (self._pressure_counter + 1) & 0xF
                if self._pressure_gen == pressure_gen:
                    self._pressure_dirty = False
                self._next_pressure_t = now + self._pressure_period
                if sent:
                    self._tally.count('pressure_frames_sent')

    def _drop_pending(self) -> None:
        """(De)activation: a command not yet on the bus never will be. Lock held."""
        if self._origin is not None:
            self._tally.count('commands_superseded')
        self._origin = None

    def _account_age(self, age: float) -> None:
        """The pending command reached the bus ``age`` s after its origin. Lock held."""
        self._origin = None
        self._tally.count('commands_on_bus')
        self.max_command_age_s = max(self.max_command_age_s, age)
        if age > self._config.stale_command_s:
            self._tally.count('stale_commands')
            self._tally.mark('stale_command', time.monotonic())
            self.last_stale_age_s = age

    def _send(self, link: BusLink, name: str, signals: dict, counter: int) -> bool:
        try:
            msg = self._codec.encode(name, signals, counter)
        except ProtocolEncodeError as err:   # clamped before: this is a bug, never send raw
            with self._lock:
                self._tally.count('internal_errors')
            logger.error('not sent: %s', err)
            return False
        if name == COMMAND:
            with self._lock:
                self._sent.append(bytes(msg.data))
        return link.send(msg)
