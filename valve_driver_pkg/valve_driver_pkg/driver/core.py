"""The suite's CAN driver without ROS: a small facade over the link, the scheduler and the
tracker.

:class:`CanDriverCore` is a :class:`~valve_driver_pkg.driver.core_base.DriverCoreBase`
(bus link, one lock, I/O thread, lifecycle) for the suite's own protocol. It composes

* :class:`~valve_driver_pkg.driver.transmit.TransmitScheduler`: duty command, pressures,
  watchdog, when frames are due;
* :class:`~valve_driver_pkg.driver.receive.ReceiveTracker`: frames -> counters, sequence
  checks, :class:`~valve_model_pkg.model.sample.ValveSample` (handed to ``on_state`` on
  the receive thread);
* :func:`~valve_driver_pkg.driver.diagnostics.diagnose`: snapshot -> statuses;

and its I/O thread sends what is due, runs the watchdog, judges the telemetry
(:mod:`~valve_driver_pkg.driver.health`: lost on silence or counter gaps, with
hysteresis), and reopens a failed bus every ``reopen_period_s``. Both bus threads lower
their nice value to ``io_nice`` where the system permits (:func:`raise_thread_priority`),
so other processes' load delays bus I/O less. Nothing that reads (``report``,
``counters``, ``command``) changes state.
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.driver.bus_link import raise_thread_priority
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.core_base import ClearResult, DriverCoreBase
from valve_driver_pkg.driver.diagnostics import (LATCHED_FLAGS, DriverSnapshot, Level,
                                                 StatusReport, age, diagnose, fault_flags)
from valve_driver_pkg.driver.host_command import CommandResult, HostCommand
from valve_driver_pkg.driver.receive import MassFlowFunction, ReceiveTracker
from valve_driver_pkg.driver.transmit import TransmitScheduler
from valve_driver_pkg.protocol.codec import ValveCodec
from valve_model_pkg.model.sample import ValveSample

__all__ = ['CanDriverCore', 'DriverConfig', 'CommandResult', 'Level', 'StatusReport',
           'MassFlowFunction', 'ClearResult', 'raise_thread_priority']

logger = logging.getLogger(__name__)

#: The I/O thread re-evaluates the diagnostic levels at least this often [s].
_LEVEL_CHECK_S = 0.05


class CanDriverCore(DriverCoreBase):
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
        super().__init__(config, on_diagnostics_changed, bus_factory, 'valve_can_io')
        self.codec = ValveCodec(config.node_id, config.dbc_path or None)
        self.scheduler = TransmitScheduler(config, self.codec, self._lock, self._tally)
        self.tracker = ReceiveTracker(config, self.codec, self._lock, self._tally, self.link,
                                      self.scheduler, mass_flow, on_state,
                                      self._check_levels)
        self._next_level_check = 0.0

    @property
    def frame_clock(self) -> Callable[[], float]:
        """The clock received frames are stamped against (:attr:`ReceiveTracker.frame_clock
        <valve_driver_pkg.driver.receive.ReceiveTracker.frame_clock>`)."""
        return self.tracker.frame_clock

    @frame_clock.setter
    def frame_clock(self, clock: Callable[[], float]) -> None:
        self.tracker.frame_clock = clock

    @property
    def host_command(self) -> HostCommand:
        return self.scheduler

    # --- lifecycle ---------------------------------------------------------------------------
    def _on_open(self, now: float) -> None:
        self.tracker.on_open(now)
        self._next_level_check = 0.0

    def _after_open(self) -> None:
        logger.info('CAN bus %s open; DBC %s', self.config.hardware_id, self.codec.dbc_path)

    def activate(self) -> None:
        """Start sending commands; the command starts at duty 0 until one arrives."""
        with self._lock:
            self.scheduler.activate()

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
        """Send ``ClearFaults=1`` once and read what is left from the controller's
        ``ValveStatus`` after it (see :meth:`_flags_after`).

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
        after = self._flags_after(sent, deadline)
        if after is None:
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

    def _flags_after(self, sent: float, deadline: float) -> list[str] | None:
        """The fault flags once the controller has handled a frame sent at ``sent``: those of
        the first ValveStatus after it that shows no latched flag, else of the last one by
        ``deadline`` (the protocol has no acknowledgment: a status may have left a busy
        controller before it handled the frame); None if no status came."""
        after, last = None, sent + 0.001
        while time.monotonic() < deadline:
            with self._lock:
                mono = self.tracker.last_status_mono
                if mono is not None and mono > last:
                    last = mono
                    after = fault_flags(self.tracker.last_status)
            if after is not None and not any(f in LATCHED_FLAGS for f in after):
                break
            time.sleep(0.005)
        return after

    def handle_frame(self, msg: can.Message) -> None:
        """The receive path for one frame, as the receive thread hands it on (error frames
        go to the link's bus condition, the others to the receive tracker)."""
        if msg.is_error_frame:
            self.link.on_error_frame(msg)
        else:
            self.tracker.on_frame(msg)

    # --- diagnostics -------------------------------------------------------------------------
    def snapshot(self) -> DriverSnapshot:
        """Copy the state the diagnostics need, under the lock."""
        now = time.monotonic()
        link, tracker, sched = self.link, self.tracker, self.scheduler
        with self._lock:
            return DriverSnapshot(
                config=self.config, now=now, counters=self._tally.copy(),
                recent=self._tally.recent(now, self.config.fault_hold_s),
                closed=self._closed, active=sched.active, bus=link.snapshot(),
                last_reject=tracker.last_reject,
                telemetry_age_s=age(now, tracker.last_valid_mono),
                telemetry_lost=tracker.lost, lost_after_s=tracker.lost_after_s,
                loss_reason=tracker.health.reason,
                frozen_run=tracker.frozen_run, frozen_counter=tracker.frozen_counter,
                telemetry_rate_hz=tracker.rate_hz,
                average_source=tracker.average_source(),
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

    @staticmethod
    def default_dbc_path() -> Path:
        from valve_driver_pkg.protocol.codec import default_dbc_path
        return default_dbc_path()

    # --- I/O thread --------------------------------------------------------------------------
    def _io_round(self) -> None:
        now = time.monotonic()
        if self.link.failed and now >= self.link.next_reopen:
            self._reopen()
            return
        changed = self.tracker.check_loss(now)
        changed |= self.scheduler.check_watchdog(now)
        if changed:
            self._check_levels()
        self.scheduler.send_due(now, self.link)
        if now >= self._next_level_check:
            self.tracker.update_rate(now)
            self._check_levels()
            self._next_level_check = now + _LEVEL_CHECK_S
        self._wait(self._next_level_check)

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
