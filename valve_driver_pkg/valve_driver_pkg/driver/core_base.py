"""What every driver core shares: the bus link, the one lock, the I/O thread, the lifecycle.

:class:`DriverCoreBase` is the skeleton of the suite's core
(:class:`~valve_driver_pkg.driver.core.CanDriverCore`) and of the device protocols' core
(:class:`~valve_driver_pkg.devices.core.DeviceDriverCore`), so the node drives either
through one face: :meth:`open`, ``activate``, :meth:`deactivate`, :meth:`close`,
:meth:`set_command`, :meth:`set_pressures`, ``report``. It owns

* one lock (a ``threading.Condition`` over an ``RLock``) that guards every part's state;
  bus I/O and callbacks run outside it;
* the :class:`~valve_driver_pkg.driver.bus_link.BusLink` (the bus, the receive thread,
  the bus condition), which hands every frame to :meth:`handle_frame`;
* the **I/O thread**, which runs the subclass's :meth:`_io_round` until the core closes
  and survives any error in it (counted as ``internal_errors``);
* the change notification: ``on_diagnostics_changed`` is called whenever a diagnostic
  level differs from the last check.

A subclass provides its command state (:attr:`host_command`), :meth:`handle_frame`,
:meth:`_io_round`, ``report`` and the hooks of open and close.
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can

from valve_driver_pkg.driver.bus_link import BusLink, raise_thread_priority
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.diagnostics import Level, StatusReport, Tally, overall_level
from valve_driver_pkg.driver.frame_log import FrameLog
from valve_driver_pkg.driver.host_command import CommandResult, HostCommand

__all__ = ['DriverCoreBase', 'ClearResult']

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ClearResult:
    """What ``clear_faults`` achieved."""

    success: bool
    cleared: tuple[str, ...]
    still_active: tuple[str, ...]
    message: str

    @classmethod
    def judged(cls, action: str, before: tuple[str, ...],
               after: tuple[str, ...]) -> ClearResult:
        """The faults ``before`` and ``after`` the clear ``action``: success if none is left."""
        cleared = tuple(text for text in before if text not in after)
        return cls(not after, cleared, after,
                   f'{action}: cleared: {", ".join(cleared) or "nothing"}; still active: '
                   f'{", ".join(after) or "nothing"}')


class DriverCoreBase:
    """The skeleton of a driver core (module docstring). Thread-safe.

    Parameters
    ----------
    config : DriverConfig
    on_diagnostics_changed : callable | None
        ``on_diagnostics_changed()``, called on a driver thread when a level changes.
    bus_factory : callable
        ``bus_factory(interface, channel, bitrate, connect_timeout)``; tests inject buses.
    io_thread_name : str
        The I/O thread's name.
    join_timeout_s : float
        How long :meth:`close` waits for each thread [s].
    """

    def __init__(self, config: DriverConfig,
                 on_diagnostics_changed: Callable[[], None] | None,
                 bus_factory: Callable[..., can.BusABC], io_thread_name: str,
                 join_timeout_s: float = 2.0) -> None:
        self.config = config
        self._on_diag = on_diagnostics_changed
        self._lock = threading.Condition(threading.RLock())
        self._stop = threading.Event()
        self._tally = Tally()
        self._closed = True
        self._levels: tuple[Level, ...] = ()
        self._io_thread: threading.Thread | None = None
        self._io_thread_name = io_thread_name
        self._join_timeout_s = join_timeout_s
        self.io_priority_raised = False
        self.link = BusLink(config, self._lock, self._tally, self._stop, self.handle_frame,
                            self._check_levels, bus_factory)

    # --- what a subclass provides -----------------------------------------------------------
    @property
    def host_command(self) -> HostCommand:
        """The host's command state (duty, watchdog, deactivate's duty-0 frame)."""
        raise NotImplementedError

    def handle_frame(self, msg: can.Message) -> None:
        """The receive path for one frame, as the receive thread hands it on."""
        raise NotImplementedError

    def report(self) -> list[StatusReport]:
        """The driver's diagnostics now."""
        raise NotImplementedError

    def _io_round(self) -> None:
        """One round of the I/O thread: what is due now, then wait for the next thing."""
        raise NotImplementedError

    def _on_open(self, now: float) -> None:
        """The bus is open, the I/O thread not yet running. Lock held."""

    def _after_open(self) -> None:
        """The I/O thread runs; a raise closes the core again and reaches open's caller."""

    def _on_close(self) -> None:
        """The core closes (threads still running). Lock held."""

    def _other_threads(self) -> list[threading.Thread | None]:
        """Threads besides the I/O thread that close waits for."""
        return []

    def _release(self) -> None:
        """The threads have ended: release what the subclass holds (bus still open)."""

    # --- lifecycle ---------------------------------------------------------------------------
    def open(self) -> None:
        """Open the bus, start the I/O thread and whatever the subclass does then.

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
            self._on_open(time.monotonic())
        self._io_thread = threading.Thread(target=self._io_loop, name=self._io_thread_name,
                                           daemon=True)
        self._io_thread.start()
        try:
            self._after_open()
        except BaseException:
            self.close()
            raise

    def deactivate(self, timeout_s: float = 0.2) -> bool:
        """Command duty 0 (output disabled), wait until that frame is sent, stop sending.

        Returns
        -------
        bool
            True if the duty-0 frame went out within ``timeout_s``.
        """
        command = self.host_command
        with self._lock:
            if not command.deactivate():
                return True
            deadline = time.monotonic() + timeout_s
            while (command.disable_pending and not self._closed
                   and time.monotonic() < deadline):
                self._lock.wait(deadline - time.monotonic())
            return not command.disable_pending

    def close(self) -> None:
        """Stop the threads, release the subclass's parts, close the bus; safe twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self.host_command.active = False
            self._on_close()
            self._stop.set()
            self._lock.notify_all()
        for thread in (self._io_thread, *self._other_threads()):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=self._join_timeout_s)
        self._io_thread = None
        self._release()
        self.link.close()
        log, self.link.frame_log = self.link.frame_log, None
        if log is not None:
            log.close()

    @property
    def is_open(self) -> bool:
        return not self._closed

    @property
    def is_active(self) -> bool:
        return self.host_command.active

    # --- inputs ------------------------------------------------------------------------------
    def set_command(self, duty: float, pwm_frequency_hz: float = 0.0, age_s: float = 0.0,
                    sequence: int | None = None, source: str = '') -> CommandResult:
        """See :meth:`HostCommand.set_command`; wakes the I/O thread."""
        return self.host_command.set_command(duty, pwm_frequency_hz, age_s, sequence, source)

    def set_pressures(self, supply_pa: float | None = None,
                      output_pa: float | None = None) -> bool:
        """Set the port pressures (gauge Pa); a non-finite value is rejected (False)."""
        return self.host_command.set_pressures(supply_pa, output_pa)

    @property
    def command(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` the driver sends (0 while the watchdog holds)."""
        return self.host_command.command

    # --- diagnostics -------------------------------------------------------------------------
    @property
    def counters(self) -> dict[str, int]:
        """A copy of every counter of the driver."""
        with self._lock:
            return self._tally.copy()

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

    # --- I/O thread --------------------------------------------------------------------------
    def _io_loop(self) -> None:
        self.io_priority_raised = raise_thread_priority(
            self.config.io_nice, 'I/O', self.config.io_realtime_priority)
        while not self._stop.is_set():
            try:
                self._io_round()
            except Exception:   # noqa: BLE001 - the I/O thread must survive anything
                with self._lock:
                    self._tally.count('internal_errors')
                logger.exception('unexpected error in the CAN I/O thread')
                self._stop.wait(0.01)
