"""The driver's bus link: open, close and reopen the bus; the bus condition.

:class:`BusLink` owns the python-can bus and its ``can.Notifier`` (the receive thread).
Received frames go to the ``on_frame`` callback given at construction; error frames and
receive failures change the bus condition kept here. All its state is guarded by the
driver core's one lock (passed in); :meth:`open` and :meth:`close` take it only briefly,
never while waiting for the receive thread.
"""
from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable

import can

from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import BusSnapshot, Tally
from valve_driver_pkg.driver.frame_log import FrameLog
from valve_driver_pkg.errors import BusOpenError
from valve_driver_pkg.protocol.error_frames import BusCondition, parse_error_frame

__all__ = ['BusLink', 'raise_thread_priority']

logger = logging.getLogger(__name__)

#: How long a reopen attempt waits for the bus [s] (the I/O thread must not stall long).
_REOPEN_TIMEOUT_S = 0.2
#: Kinds of thread whose missing permission was already logged (one INFO line each).
_priority_noted: set[str] = set()


def raise_thread_priority(nice: int, what: str, realtime: int = 0) -> bool:
    """Raise the calling thread's priority (Linux: per thread); quiet fallback.

    ``realtime`` > 0 asks for SCHED_FIFO at that priority, else the nice value ``nice``.
    Both need CAP_SYS_NICE below the defaults (root, or ``ulimit -e`` / ``-r``); without it
    the thread keeps its priority and one INFO line says so (per kind of thread).

    Returns
    -------
    bool
        True if the priority was changed.
    """
    tid = threading.get_native_id()
    try:
        if realtime > 0 and hasattr(os, 'sched_setscheduler'):
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(realtime))
            return True
        if nice == 0 or not hasattr(os, 'setpriority'):
            return False
        os.setpriority(os.PRIO_PROCESS, tid, nice)
        return True
    except OSError as err:
        if what not in _priority_noted:
            _priority_noted.add(what)
            logger.info('CAN %s thread keeps its priority (%s not permitted: %s)', what,
                        f'SCHED_FIFO {realtime}' if realtime > 0 else f'nice {nice}',
                        err.strerror or err)
        return False


class _Listener(can.Listener):
    """Notifier callback: hands frames on; a receive failure marks the bus failed."""

    def __init__(self, link: BusLink) -> None:
        self._link = link
        self._thread_id: int | None = None

    def on_message_received(self, msg: can.Message) -> None:
        if self._thread_id != threading.get_native_id():   # first frame on this thread
            self._thread_id = threading.get_native_id()
            raise_thread_priority(self._link.nice, 'receive', self._link.realtime)
        self._link._deliver(msg)

    def on_error(self, exc: Exception) -> None:
        self._link.on_bus_error(exc)


class BusLink:
    """The bus, its receive thread and its condition.

    Parameters
    ----------
    config : DriverConfig
    lock : threading.Condition
        The driver core's lock; every attribute here changes only while holding it.
    tally : Tally
        Counters: ``error_frames``, ``error_passive_events``, ``bus_off_events``,
        ``bus_recoveries``, ``bus_failures``, ``bus_reopens``, ``tx_errors``,
        ``internal_errors`` (a frame handler raised).
    stop : threading.Event
        Set while the core closes; a failing receive loop waits on it.
    on_frame : callable
        ``on_frame(msg)`` for every received frame, on the receive thread.
    on_change : callable
        ``on_change()`` after the condition changed (outside the lock).
    bus_factory : callable
        ``bus_factory(interface, channel, bitrate, connect_timeout=...)``.
    """

    def __init__(self, config: DriverConfig, lock: threading.Condition, tally: Tally,
                 stop: threading.Event, on_frame: Callable[[can.Message], None],
                 on_change: Callable[[], None], bus_factory: Callable[..., can.BusABC]) -> None:
        self._config = config
        self._lock = lock
        self._tally = tally
        self._stop = stop
        self._on_frame = on_frame
        self._on_change = on_change
        self._bus_factory = bus_factory
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self.failed = False
        self.error_text = ''
        self.next_reopen = 0.0
        self.condition = BusCondition.ERROR_ACTIVE
        self.last_error_frame = ''
        self.nice = config.io_nice
        self.realtime = config.io_realtime_priority
        self.bus_off_since = 0.0
        self._polled = False      # the condition came from python-can's bus state
        #: Every frame received and sent goes here too when set (``log_frames_file``).
        self.frame_log: FrameLog | None = None

    # --- open / close (caller's thread or the I/O thread) ------------------------------------
    def open(self, connect_timeout: float | None = None) -> None:
        """Open the bus and start the receive thread.

        Raises
        ------
        BusOpenError
            The bus could not be opened; nothing is left open.
        """
        cfg = self._config
        timeout = cfg.open_timeout_s if connect_timeout is None else connect_timeout
        bus = self._bus_factory(cfg.interface, cfg.channel, cfg.bitrate,
                                connect_timeout=timeout)
        try:
            notifier = can.Notifier(bus, [_Listener(self)], timeout=0.1)
        except Exception as err:
            bus.shutdown()
            raise BusOpenError(f'cannot start receiving on {cfg.interface}:{cfg.channel}: '
                               f'{err}') from err
        with self._lock:
            self._bus, self._notifier = bus, notifier
            self.failed = False

    def close(self) -> None:
        """Stop the receive thread and close the bus; safe to call more than once."""
        with self._lock:
            bus, notifier = self._bus, self._notifier
            self._bus, self._notifier = None, None
        if notifier is not None:
            notifier.stop(timeout=1.0)   # joins the receive thread: never under the lock
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as err:
                logger.debug('bus shutdown: %s', err)

    def reopen(self) -> bool:
        """Close the failed bus and try once to open it again (I/O thread).

        Returns
        -------
        bool
            True if the bus is open again; otherwise the next attempt is due after
            ``reopen_period_s``.
        """
        cfg = self._config
        self.close()
        with self._lock:
            self._tally.count('bus_reopens')
        try:
            self.open(min(_REOPEN_TIMEOUT_S, cfg.open_timeout_s))
        except BusOpenError as err:
            with self._lock:
                self.next_reopen = time.monotonic() + cfg.reopen_period_s
            logger.debug('reopen failed: %s', err)
            return False
        logger.info('CAN bus %s:%s reopened', cfg.interface, cfg.channel)
        return True

    # --- sending (I/O thread) ----------------------------------------------------------------
    @property
    def usable(self) -> bool:
        """True while a bus is open and has not failed."""
        return self._bus is not None and not self.failed

    def send(self, msg: can.Message) -> bool:
        """Send one frame (10 ms timeout); a failure is counted, marked and logged."""
        bus = self._bus
        if bus is None or self.failed:
            return False
        try:
            bus.send(msg, timeout=0.01)
            if self.frame_log is not None:
                self.frame_log.write(msg, received=False)
            return True
        except can.CanError as err:
            with self._lock:
                self._tally.count('tx_errors')
                self._tally.mark('tx_error', time.monotonic())
            logger.debug('send failed: %s', err)
            return False

    def snapshot(self) -> BusSnapshot:
        """The link's state for the diagnostics. Lock held."""
        return BusSnapshot(self.failed, self.error_text, self.condition, self.last_error_frame)

    # --- receive thread ----------------------------------------------------------------------
    @property
    def bus(self) -> can.BusABC | None:
        """The open python-can bus (None while closed)."""
        return self._bus

    def _deliver(self, msg: can.Message) -> None:
        if self.frame_log is not None:
            self.frame_log.write(msg, received=True)
        try:
            if msg.is_error_frame:
                self.on_error_frame(msg)
            else:
                self._on_frame(msg)
        except Exception:   # noqa: BLE001 - nothing a frame does may stop the receive thread
            with self._lock:
                self._tally.count('internal_errors')
            logger.exception('unexpected error handling a frame; frame dropped')

    def on_error_frame(self, msg: can.Message) -> None:
        """Follow the controller state an error frame reports (receive thread)."""
        info = parse_error_frame(msg)
        with self._lock:
            self._tally.count('error_frames')
            self._tally.mark('error_frame', time.monotonic())
        self.apply_condition(info.condition, info.text)

    def poll_state(self) -> None:
        """Follow python-can's bus state (``bus.state``: active, passive, bus-off).

        Interfaces that report no state answer ``ACTIVE`` (python-can's default) and leave
        the condition to the error frames; ``ACTIVE`` ends only a condition that the bus
        state itself reported.
        """
        bus = self._bus
        if bus is None or self.failed:
            return
        try:
            state = bus.state
        except (NotImplementedError, can.CanError, OSError):
            return
        if state is can.BusState.PASSIVE and self.condition is not BusCondition.ERROR_PASSIVE:
            self._polled = True
            self.apply_condition(BusCondition.ERROR_PASSIVE, 'python-can bus state: passive')
        elif state is can.BusState.ERROR and self.condition is not BusCondition.BUS_OFF:
            self._polled = True
            self.apply_condition(BusCondition.BUS_OFF, 'python-can bus state: bus-off')
        elif (state is can.BusState.ACTIVE and self._polled
              and self.condition is not BusCondition.ERROR_ACTIVE):
            self._polled = False
            self.apply_condition(BusCondition.ERROR_ACTIVE, 'python-can bus state: active')

    def apply_condition(self, condition: BusCondition, text: str) -> None:
        """Enter the controller state ``condition`` reported by ``text`` (any thread)."""
        with self._lock:
            self.last_error_frame = text
            previous = self.condition
            if condition is BusCondition.BUS_OFF:
                if previous is not BusCondition.BUS_OFF:
                    self._tally.count('bus_off_events')
                    self.bus_off_since = time.monotonic()
                self.condition = BusCondition.BUS_OFF
            elif condition is BusCondition.ERROR_PASSIVE:
                if previous is not BusCondition.ERROR_PASSIVE:
                    self._tally.count('error_passive_events')
                if previous is not BusCondition.BUS_OFF:
                    self.condition = BusCondition.ERROR_PASSIVE
            elif condition is BusCondition.WARNING:
                if previous is BusCondition.ERROR_ACTIVE:
                    self.condition = BusCondition.WARNING
            elif condition in (BusCondition.RESTARTED, BusCondition.ERROR_ACTIVE):
                if previous is not BusCondition.ERROR_ACTIVE:
                    self._tally.count('bus_recoveries')
                self.condition = BusCondition.ERROR_ACTIVE
            changed = self.condition is not previous
        if changed:
            logger.warning('CAN bus %s: %s', self.condition.value, text)
            self._on_change()

    def note_valid_traffic(self) -> None:
        """Valid frames flow: a bus-off is over even without a "restarted" error frame.

        Called with the lock held (by the receive tracker).
        """
        if self.condition is BusCondition.BUS_OFF:
            self.condition = BusCondition.ERROR_ACTIVE
            self._tally.count('bus_recoveries')

    def on_bus_error(self, exc: Exception) -> None:
        """The receive loop failed (adapter down, hub gone): reopen from the I/O thread."""
        with self._lock:
            first = not self.failed
            self.failed = True
            self.error_text = str(exc)
            if first:
                self._tally.count('bus_failures')
            self._lock.notify_all()
        if first:
            logger.error('CAN bus failed: %s; reopening every %.1f s', exc,
                         self._config.reopen_period_s)
            self._on_change()
        # The notifier calls recv() again at once; do not spin on a dead bus.
        self._stop.wait(0.05)
