"""The CAN driver without ROS: a small facade over the link, the scheduler and the tracker.

:class:`CanDriverCore` composes

* :class:`~valve_driver_pkg.driver.bus_link.BusLink`: the bus, the **receive thread** (a
  ``can.Notifier``), the bus condition;
* :class:`~valve_driver_pkg.driver.transmit.TransmitScheduler`: duty command, pressures,
  watchdog, when frames are due;
* :class:`~valve_driver_pkg.driver.receive.ReceiveTracker`: frames -> counters, sequence
  checks, :class:`~valve_model_pkg.model.sample.ValveSample` (handed to ``on_state`` on
  the receive thread);
* :func:`~valve_driver_pkg.driver.diagnostics.diagnose`: snapshot -> statuses;

and runs the **I/O thread**: it sends what is due, runs the watchdog, judges the
telemetry (:mod:`~valve_driver_pkg.driver.health`: lost on silence or counter gaps, with
hysteresis), and reopens a failed bus every ``reopen_period_s``. Whenever a diagnostic
level changes it calls ``on_diagnostics_changed`` at once. Both bus threads lower their
nice value to ``io_nice`` where the system permits (:func:`raise_thread_priority`), so
other processes' load delays bus I/O less.

Thread ownership: one lock (``threading.Condition`` over an ``RLock``) guards the state of
all four parts; every write happens under it, callbacks and bus I/O happen outside it.
The I/O thread waits on the same condition, so a new command wakes it. Nothing that reads
(``report``, ``counters``, ``command``) changes state.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.driver.bus_link import BusLink, raise_thread_priority
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import (LATCHED_FLAGS, DriverSnapshot, Level,
                                                 StatusReport, Tally, age, diagnose,
                                                 fault_flags, overall_level)
from valve_driver_pkg.driver.frame_log import FrameLog
from valve_driver_pkg.driver.receive import MassFlowFunction, ReceiveTracker
from valve_driver_pkg.driver.transmit import CommandResult, TransmitScheduler
from valve_driver_pkg.protocol.codec import ValveCodec
from valve_model_pkg.model.sample import ValveSample

__all__ = ['CanDriverCore', 'DriverConfig', 'CommandResult', 'Level', 'StatusReport',
           'MassFlowFunction', 'ClearResult', 'raise_thread_priority']

logger = logging.getLogger(__name__)

#: The I/O thread re-evaluates the diagnostic levels at least this often [s].
_LEVEL_CHECK_S = 0.05


@dataclass(frozen=True, slots=True)
class ClearResult:
    """What :meth:`CanDriverCore.clear_faults` achieved."""

    success: bool
    cleared: tuple[str, ...]
    still_active: tuple[str, ...]
    message: str


class CanDriverCore:
    """The driver without ROS. Thread-safe; see the module docstring for the threads.

    Parameters
    ----------
    config : DriverConfig
    mass_flow : MassFlowFunction | None
        Orifice equation for the derived mass flow; ``None`` reports 0.
    on_state : callable | None
        ``on_state(ValveSample)``, called on the receive thread for every valid telemetry
        frame while the driver is active.
    on_diagnostics_changed : callable | None
        ``on_diagnostics_changed()``, called (on a driver thread) when a level changes.
    bus_factory : callable
        ``bus_factory(interface, channel, bitrate, connect_timeout)``; tests inject buses.
    """

    def __init__(self, config: DriverConfig, mass_flow: MassFlowFunction | None = None,
                 on_state: Callable[[ValveSample], None] | None = None,
                 on_diagnostics_changed: Callable[[], None] | None = None,
                 bus_factory: Callable[..., can.BusABC] = open_bus) -> None:
        self.config = config
        self.codec = ValveCodec(config.node_id, config.dbc_path or None)
        self._on_diag = on_diagnostics_changed
        self._lock = threading.Condition(threading.RLock())
        self._stop = threading.Event()
        self._tally = Tally()
        self._closed = True
        self._levels: tuple[Level, ...] = ()
        self._io_thread: threading.Thread | None = None
        self.io_priority_raised = False
        self.link = BusLink(config, self._lock, self._tally, self._stop, self._on_frame,
                            self._check_levels, bus_factory)
        self.scheduler = TransmitScheduler(config, self.codec, self._lock, self._tally)
        self.tracker = ReceiveTracker(config, self.codec, self._lock, self._tally, self.link,
                                      self.scheduler, mass_flow, on_state,
                                      self._check_levels)

    # --- lifecycle ---------------------------------------------------------------------------
    def open(self) -> None:
        """Open the bus and start receiving (no frames are sent until :meth:`activate`).

        Raises
        ------
        BusOpenError
            The bus could not be opened; nothing is left open.
        """
        if not self._closed:
            return
        self._stop.clear()
        self.link.open()
        if self.config.log_frames_file:
            self.link.frame_log = FrameLog(self.config.log_frames_file, self.config.channel)
        with self._lock:
            self._closed = False
            self.tracker.on_open(time.monotonic())
        self._io_thread = threading.Thread(target=self._io_loop, name='valve_can_io',
                                           daemon=True)
        self._io_thread.start()
        cfg = self.config
        logger.info('CAN bus %s open; DBC %s', cfg.hardware_id, self.codec.dbc_path)

    def activate(self) -> None:
        """Start sending commands; the command starts at duty 0 until one arrives."""
        with self._lock:
            self.scheduler.activate()

    def deactivate(self, timeout_s: float = 0.2) -> bool:
        """Command duty 0 (output disabled), wait until that frame is sent, stop sending.

        Returns
        -------
        bool
            True if the duty-0 frame went out within ``timeout_s``.
        """
        with self._lock:
            if not self.scheduler.deactivate():
                return True
            deadline = time.monotonic() + timeout_s
            while (self.scheduler.disable_pending and not self._closed
                   and time.monotonic() < deadline):
                self._lock.wait(deadline - time.monotonic())
            return not self.scheduler.disable_pending

    def close(self) -> None:
        """Stop the threads and close the bus; safe to call more than once."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self.scheduler.active = False
            self._stop.set()
            self._lock.notify_all()
        if self._io_thread is not None and self._io_thread is not threading.current_thread():
            self._io_thread.join(timeout=2.0)
        self._io_thread = None
        self.link.close()
        log, self.link.frame_log = self.link.frame_log, None
        if log is not None:
            log.close()

    @property
    def is_open(self) -> bool:
        return not self._closed

    @property
    def is_active(self) -> bool:
        return self.scheduler.active

    # --- inputs ------------------------------------------------------------------------------
    def set_command(self, duty: float, pwm_frequency_hz: float = 0.0, age_s: float = 0.0,
                    sequence: int | None = None, source: str = '') -> CommandResult:
        """See :meth:`TransmitScheduler.set_command`."""
        return self.scheduler.set_command(duty, pwm_frequency_hz, age_s, sequence, source)

    def set_drive_mode(self, mode: str) -> str:
        """Drive mode sent to the controller from now on (``'normal'`` | ``'bench'``).

        See :meth:`TransmitScheduler.set_drive_mode`; a change is logged. Returns the mode
        sent before (its name).

        Raises
        ------
        ValueError
            Not a drive mode name; nothing changes.
        """
        old = self.scheduler.set_drive_mode(mode)
        new = self.scheduler.drive_mode
        if new != old:
            logger.info('drive mode %s -> %s: sent in every ValveCommand; the controller '
                        'switches at its next PWM period start (at once while duty 0 is in '
                        'force)', old.name.lower(), new.name.lower())
        return old.name.lower()

    @property
    def drive_mode(self) -> str:
        """The drive mode the driver sends (name)."""
        return self.scheduler.drive_mode.name.lower()

    def clear_faults(self, timeout_s: float = 1.0) -> ClearResult:
        """Send ``ClearFaults=1`` once and wait for the controller's next ``ValveStatus``.

        Works while configured (active or not): the frame carries the command in force
        (duty 0 and ``Enable=0`` while inactive). Call it from a thread other than the
        driver's own (the node's service callback).

        Returns
        -------
        ClearResult
            ``cleared``: flags set before and gone after; ``still_active``: flags still set
            (a latched fault whose condition persists, or an active condition).
        """
        deadline = time.monotonic() + timeout_s
        with self._lock:
            if self._closed:
                return ClearResult(False, (), (), 'not cleared: the bus is closed')
            before = fault_flags(self.tracker.last_status)
            self._tally.count('fault_clear_requests')
            self.scheduler.request_clear()
            while self.scheduler.clear_pending and not self._closed:
                if not self._lock.wait(deadline - time.monotonic()) and \
                        time.monotonic() >= deadline:
                    break
            sent = self.scheduler.clear_sent_mono
            if sent is None:
                self.scheduler.clear_pending = False
                return ClearResult(False, (), tuple(before), 'not cleared: the ClearFaults '
                                   'frame could not be sent (bus down?)')
        # The controller's next heartbeat after the frame tells what is left.
        while time.monotonic() < deadline:
            with self._lock:
                mono = self.tracker.last_status_mono
                if mono is not None and mono > sent + 0.001:
                    after = fault_flags(self.tracker.last_status)
                    break
            time.sleep(0.005)
        else:
            return ClearResult(False, (), tuple(before), 'ClearFaults sent, but no ValveStatus '
                               f'from the controller within {timeout_s:g} s')
        cleared = tuple(f for f in before if f not in after)
        still = tuple(after)
        latched = [f for f in still if f in LATCHED_FLAGS]
        message = (f'cleared: {", ".join(cleared) or "nothing"}; still active: '
                   f'{", ".join(still) or "nothing"}')
        if latched:
            message += ' (latched faults stay while their condition persists)'
        logger.info('clear faults: %s', message)
        return ClearResult(not latched, cleared, still, message)

    def set_pressures(self, supply_pa: float | None = None,
                      output_pa: float | None = None) -> bool:
        """Set the port pressures (gauge Pa); a non-finite value is rejected (False)."""
        return self.scheduler.set_pressures(supply_pa, output_pa)

    @property
    def command(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` the driver sends (0 while the watchdog holds)."""
        return self.scheduler.command

    def _on_frame(self, msg: can.Message) -> None:
        """One received frame (receive thread; error frames go to the link)."""
        if msg.is_error_frame:
            self.link.on_error_frame(msg)
        else:
            self.tracker.on_frame(msg)

    # --- diagnostics -------------------------------------------------------------------------
    @property
    def counters(self) -> dict[str, int]:
        """A copy of every counter of the driver."""
        with self._lock:
            return self._tally.copy()

    def snapshot(self) -> DriverSnapshot:
        """Copy the state the diagnostics need, under the lock."""
        now = time.monotonic()
        link, tracker, sched = self.link, self.tracker, self.scheduler
        with self._lock:
            return DriverSnapshot(
                config=self.config, now=now, counters=self._tally.copy(),
                recent=self._tally.recent(now, self.config.fault_hold_s),
                closed=self._closed, active=sched.active, bus_failed=link.failed,
                bus_error_text=link.error_text, bus_condition=link.condition,
                last_error_frame=link.last_error_frame, last_reject=tracker.last_reject,
                telemetry_age_s=age(now, tracker.last_valid_mono),
                telemetry_lost=tracker.lost, lost_after_s=tracker.lost_after_s,
                loss_reason=tracker.health.reason,
                frozen_run=tracker.frozen_run, frozen_counter=tracker.frozen_counter,
                telemetry_rate_hz=tracker.rate_hz,
                average_source=tracker.average_source(now),
                last_status=tracker.last_status,
                heartbeat_age_s=age(now, tracker.last_status_mono or None),
                duty=0.0 if sched.watchdog_tripped else sched.duty,
                pwm_frequency_hz=sched.pwm_hz, watchdog_tripped=sched.watchdog_tripped,
                last_command_note=sched.last_command_note, host_id=sched.host_id,
                foreign_host_id=tracker.foreign_host_id,
                max_command_age_s=sched.max_command_age_s,
                last_stale_age_s=sched.last_stale_age_s,
                drive_mode=sched.drive_mode.name.lower(), last_drive=tracker.last_drive,
                drive_age_s=age(now, tracker.last_drive_mono))

    def report(self) -> list[StatusReport]:
        """The driver's diagnostics now: bus, telemetry, commands, controller."""
        return diagnose(self.snapshot())

    def overall_level(self) -> Level:
        """Worst level of :meth:`report` (STALE counts as ERROR)."""
        return overall_level(self.report())

    def _check_levels(self) -> None:
        """Call ``on_diagnostics_changed`` if a level differs from the last check."""
        levels = tuple(r.level for r in self.report())
        with self._lock:
            changed, self._levels = levels != self._levels, levels
        if changed and self._on_diag is not None:
            try:
                self._on_diag()
            except Exception:   # noqa: BLE001 - a callback must not stop a driver thread
                logger.exception('diagnostics callback failed')

    @staticmethod
    def default_dbc_path() -> Path:
        from valve_driver_pkg.protocol.codec import default_dbc_path
        return default_dbc_path()

    # --- I/O thread --------------------------------------------------------------------------
    def _io_loop(self) -> None:
        self.io_priority_raised = raise_thread_priority(
            self.config.io_nice, 'I/O', self.config.io_realtime_priority)
        next_level_check = 0.0
        while not self._stop.is_set():
            try:
                now = time.monotonic()
                if self.link.failed and now >= self.link.next_reopen:
                    self._reopen()
                    continue
                changed = self.tracker.check_loss(now)
                changed |= self.scheduler.check_watchdog(now)
                if changed:
                    self._check_levels()
                self.scheduler.send_due(now, self.link)
                if now >= next_level_check:
                    self.tracker.update_rate(now)
                    self._check_levels()
                    next_level_check = now + _LEVEL_CHECK_S
                self._wait(next_level_check)
            except Exception:   # noqa: BLE001 - the I/O thread must survive anything
                with self._lock:
                    self._tally.count('internal_errors')
                logger.exception('unexpected error in the CAN I/O thread')
                self._stop.wait(0.01)

    def _wait(self, next_level_check: float) -> None:
        """Sleep until something is due or a caller wakes the thread."""
        with self._lock:
            if self._stop.is_set():
                return
            now = time.monotonic()
            wait = min(self.scheduler.next_due(), next_level_check) - now
            wait = min(wait, self.tracker.loss_deadline() - now + 1e-5)
            if self.link.failed:
                wait = min(wait, self.link.next_reopen - now)
            if wait > 0.0 and not self.scheduler.urgent():
                self._lock.wait(wait)

    def _reopen(self) -> None:
        if not self.link.reopen():
            return
        with self._lock:
            self.tracker.on_open(time.monotonic())
            self.scheduler.mark_dirty()
        self._check_levels()
