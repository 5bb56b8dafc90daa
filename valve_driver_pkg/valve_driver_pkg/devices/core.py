"""The driver core for a device protocol (CANopen, J1939, DBC): set-up, liveness, restarts.

:class:`DeviceDriverCore` is a :class:`~valve_driver_pkg.driver.core_base.DriverCoreBase`
(bus link, one lock, I/O thread, lifecycle: the face the node drives) for a
:class:`~valve_driver_pkg.devices.base.DeviceProtocol`. It composes

* the protocol: frames in and out, the device's set-up, its faults;
* :class:`~valve_driver_pkg.devices.commands.CommandState`: the host's command, clamping,
  the watchdog, when a command frame is due;
* :class:`~valve_driver_pkg.devices.liveness.DeviceLiveness`: silence for
  :data:`~valve_driver_pkg.devices.base.LIVENESS_PERIODS` of the device's periods is a
  lost device (ERROR; valve/state stops);
* :class:`~valve_driver_pkg.devices.state.StateBuilder`: each reading from a live device
  while active becomes a :class:`~valve_model_pkg.model.sample.ValveSample` handed to
  ``on_state`` on the receive thread; nothing stale is published.

Its **I/O thread** sends the command frames (at once on a change, then every
``protocol.command_period_s``) and the protocol's own frames (heartbeat), judges the
device's liveness, sets up again on a **set-up thread** a device that asked for it (a
boot-up frame) or whose set-up failed (every 2 ``reopen_period_s``), and restarts the bus
with a bounded back-off: a failed bus is reopened after ``reopen_period_s`` x 2^k, k the
failed attempts in a row; a bus in bus-off for :data:`BUS_OFF_RESTART_S` that the interface
did not restart itself is closed and opened again, the k-th restart in a row no sooner
than ``reopen_period_s`` x 2^k after the one before; the factor 2^k stops at
:data:`MAX_BACKOFF_FACTOR`, and k returns to 0 once the bus has worked for the longest
back-off.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.canbus.frame_time import CLOCK_APART_S, frame_time_s
from valve_driver_pkg.devices.base import DeviceProtocol
from valve_driver_pkg.devices.commands import CommandState
from valve_driver_pkg.devices.derived import DerivedOpening
from valve_driver_pkg.devices.diagnostics import DeviceSnapshot, diagnose_device
from valve_driver_pkg.devices.liveness import DeviceLiveness
from valve_driver_pkg.devices.state import CommandContext, StateBuilder
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.core_base import ClearResult, DriverCoreBase
from valve_driver_pkg.driver.diagnostics import StatusReport
from valve_driver_pkg.driver.host_command import HostCommand
from valve_driver_pkg.driver.receive import MassFlowFunction
from valve_driver_pkg.errors import DeviceError
from valve_driver_pkg.protocol.error_frames import BusCondition
from valve_model_pkg.model.sample import ValveSample

__all__ = ['DeviceDriverCore', 'MAX_BACKOFF_FACTOR', 'BUS_OFF_RESTART_S']

logger = logging.getLogger(__name__)

#: The I/O thread re-evaluates the diagnostic levels at least this often [s].
_LEVEL_CHECK_S = 0.05
#: A bus restart waits ``reopen_period_s * 2**k``, at most this factor times.
MAX_BACKOFF_FACTOR = 16
#: A bus-off lasting this long without the interface restarting itself: the driver
#: closes and reopens the bus [s].
BUS_OFF_RESTART_S = 0.2
#: How long one set-up may take (configure, and again after a device boot-up) [s].
_SETUP_TIMEOUT_S = 5.0


class DeviceDriverCore(DriverCoreBase):
    """The driver for a device protocol without ROS (module docstring). Thread-safe.

    Parameters
    ----------
    config : DriverConfig
        Bus, rates, watchdog, pressures (``protocol`` names the protocol given here).
    protocol : DeviceProtocol
    mass_flow : MassFlowFunction | None
        Orifice equation (eq. 12); NaN flow without it.
    on_state : callable | None
        ``on_state(ValveSample)`` on the receive thread, per device reading while active.
    on_diagnostics_changed : callable | None
        Called (driver thread) when a diagnostic level changes.
    bus_factory : callable
        ``bus_factory(interface, channel, bitrate, connect_timeout)``.
    setup_timeout_s : float
        How long one set-up of the device may take [s].
    derived : DerivedOpening | None
        The duty map for a device that reports no spool position: the period-mean
        position at the duty in force (and the flow from it); NaN without it.
    """

    def __init__(self, config: DriverConfig, protocol: DeviceProtocol,
                 mass_flow: MassFlowFunction | None = None,
                 on_state: Callable[[ValveSample], None] | None = None,
                 on_diagnostics_changed: Callable[[], None] | None = None,
                 bus_factory: Callable[..., can.BusABC] = open_bus,
                 setup_timeout_s: float = _SETUP_TIMEOUT_S,
                 derived: DerivedOpening | None = None) -> None:
        super().__init__(config, on_diagnostics_changed, bus_factory, 'valve_device_io',
                         join_timeout_s=setup_timeout_s)
        self.protocol = protocol
        self._on_state = on_state
        self._setup_timeout_s = setup_timeout_s
        self._setup_thread: threading.Thread | None = None
        self.commands = CommandState(config, self._lock, self._tally)
        self.liveness = DeviceLiveness(protocol.liveness_period_s)
        self._states = StateBuilder(mass_flow, derived)
        #: The clock a frame's timestamp is checked against and that stamps a frame
        #: without one [s]: the wall clock, or the node's (simulation) clock.
        self.frame_clock: Callable[[], float] = time.time
        self.started = False            # activated since open: the protocol's own frames run
        self.setup_state = 'not set up'
        self.setup_ok = False
        self._next_setup = math.inf
        self._restarts_in_row = 0       # k of the back-off
        self._last_restart_mono = -math.inf
        self._backoff_s = 0.0           # the wait scheduled after the last reopen or restart
        self._next_command_t = 0.0
        self._next_level_check = 0.0

    @property
    def host_command(self) -> HostCommand:
        return self.commands

    # --- lifecycle ---------------------------------------------------------------------------
    def _on_open(self, now: float) -> None:
        self.protocol.attach(self._send, self.link.bus)
        self.liveness.start(now)
        self._next_level_check = 0.0

    def _after_open(self) -> None:
        """Set the device up (DeviceSetupError, SdoAbortError: the bus is closed again)."""
        self._run_setup()
        logger.info('CAN bus %s:%s open; %s set up', self.config.interface,
                    self.config.channel, self.protocol.label)

    def activate(self) -> None:
        """Start the device (CANopen: NMT start) and send commands; duty 0 until one comes."""
        for msg in self.protocol.start_frames():
            self._send(msg)
        with self._lock:
            self.started = True
            self.commands.activate()
            self._next_command_t = 0.0

    def _on_close(self) -> None:
        self.started = False

    def _other_threads(self) -> list[threading.Thread | None]:
        thread, self._setup_thread = self._setup_thread, None
        return [thread]

    def _release(self) -> None:
        self.protocol.close()

    # --- what the protocols cannot share -----------------------------------------------------
    def set_drive_mode(self, mode: str) -> str:
        """Device protocols carry no drive mode (the device's own configuration holds its
        electronics): only ``normal`` is accepted.

        Raises
        ------
        ValueError
            Any other mode, naming the protocol.
        """
        if mode != 'normal':
            raise ValueError(f'drive_mode {mode!r}: protocol {self.protocol.name} carries no '
                             'drive mode (the device\'s own configuration sets its '
                             'electronics); only normal')
        return 'normal'

    @property
    def drive_mode(self) -> str:
        return 'normal'

    def clear_faults(self, timeout_s: float | None = None) -> ClearResult:
        """Ask the device to clear its faults as its protocol allows, and say what is left.

        CANopen: NMT reset communication (the device boots, is set up again and started;
        the EMCYs it sends then are what is left); J1939: DM11 (clear active DTCs), then
        the device's next DM1; DBC: refused (a user's DBC has no such message). Call it
        from a thread other than the driver's own (the node's service callback).
        """
        with self._lock:
            if self._closed:
                return ClearResult(False, (), (), 'not cleared: the bus is closed')
            self._tally.count('fault_clear_requests')
        return self.protocol.clear_faults(
            self.protocol.clear_timeout_s if timeout_s is None else timeout_s)

    # --- set-up ------------------------------------------------------------------------------
    def _run_setup(self) -> None:
        """Set the device up (caller's or set-up thread); the state says how it went."""
        with self._lock:
            self.setup_state = 'setting up'
            self.setup_ok = False
            self.protocol.needs_setup = False
        self._check_levels()
        try:
            self.protocol.setup(self._setup_timeout_s)
        except (DeviceError, OSError) as err:
            with self._lock:
                self.setup_state = f'set-up failed: {err}'
                self._tally.count('setup_failures')
                self._next_setup = time.monotonic() + self.config.reopen_period_s * 2
            logger.error('%s: set-up failed: %s', self.protocol.label, err)
            self._check_levels()
            raise
        with self._lock:
            self.setup_state = 'set up'
            self.setup_ok = True
            self._tally.count('setups')
            self._next_setup = math.inf
            started = self.started
        if started:
            for msg in self.protocol.start_frames():
                self._send(msg)
            with self._lock:
                self._next_command_t = 0.0
                self._lock.notify_all()
        self._check_levels()

    def _setup_worker(self) -> None:
        try:
            self._run_setup()
            logger.info('%s set up again', self.protocol.label)
        except (DeviceError, OSError):
            pass   # logged and counted; retried by the I/O thread

    def _maybe_start_setup(self, now: float) -> None:
        if self._setup_thread is not None and self._setup_thread.is_alive():
            return
        with self._lock:
            due = self.protocol.needs_setup or (not self.setup_ok and now >= self._next_setup)
            if not due or self._closed:
                return
            self.protocol.needs_setup = False
            self._next_setup = math.inf
        self._setup_thread = threading.Thread(target=self._setup_worker,
                                              name='valve_device_setup', daemon=True)
        self._setup_thread.start()

    # --- receive thread ----------------------------------------------------------------------
    def handle_frame(self, msg: can.Message) -> None:
        """The receive path for one (non-error) frame: the protocol reads it; a frame from
        the device keeps it alive; a reading from a live device while active is published.

        A device frame older than the device's silence limit when it is handled (its
        timestamp: the interface's receive time, or the sender's on ``tcp_loopback``) is
        stale: counted (``stale_frames``), neither proof of life nor published. A timestamp
        more than :data:`CLOCK_APART_S` from the wall clock is another clock's (some
        adapters count from their own start) and is not judged. A published state is
        stamped with the frame's time (:func:`~valve_driver_pkg.canbus.frame_time.
        frame_time_s`).
        """
        outcome = self.protocol.on_frame(msg)
        if not outcome.from_device:
            return
        now = time.monotonic()
        wall = time.time()
        age = wall - msg.timestamp if msg.timestamp else 0.0
        stamp = frame_time_s(msg.timestamp, self.frame_clock())
        with self._lock:
            if self.liveness.limit_s < age < CLOCK_APART_S:
                self._tally.count('stale_frames')
                self._tally.mark('stale_frame', now)
                return
            back = self.liveness.heard(now)
            self._tally.count('device_frames')
            self.link.note_valid_traffic()
            sample = None
            if outcome.reading is not None and self.commands.active:
                duty_sent, pwm_hz = self.commands.sent
                sends_freq = self.protocol.sends_pwm_frequency
                sample = self._states.sample(outcome.reading, CommandContext(
                    duty_sent, pwm_hz if sends_freq else self.config.pwm_frequency_hz,
                    sends_freq, self.commands.supply_pa, self.commands.output_pa),
                    now - (wall - stamp), stamp)
        if back:
            logger.info('%s is back', self.protocol.label)
            self._check_levels()
        if sample is not None and self._on_state is not None:
            self._on_state(sample)

    # --- I/O thread --------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> bool:
        sent = self.link.send(msg)
        if sent:
            with self._lock:
                self._tally.count('frames_sent')
        return sent

    def _io_round(self) -> None:
        now = time.monotonic()
        if self._restart_bus_if_due(now):
            return
        changed = self._check_device(now)
        changed |= self.commands.check_watchdog(now)
        if changed:
            self._check_levels()
        self._maybe_start_setup(now)
        self._send_due(now)
        if now >= self._next_level_check:
            self.link.poll_state()
            self._check_levels()
            self._next_level_check = now + _LEVEL_CHECK_S
        self._wait()

    def _send_due(self, now: float) -> None:
        protocol = self.protocol
        with self._lock:
            frame = self.commands.due(now, self._next_command_t)
            pwm_hz = self.commands.pwm_hz
            started = self.started
            if frame is not None:
                self._next_command_t = now + protocol.command_period_s
        if not self.link.usable:
            return
        if frame is not None:
            duty, enable, disabling = frame
            protocol.set_frequency(pwm_hz)
            sent = all([self._send(m) for m in protocol.command_frames(duty, enable)])
            self.commands.sent_frame(duty, sent, disabling)
        for msg in protocol.own_frames(now, started):
            self._send(msg)

    def _wait(self) -> None:
        with self._lock:
            if self._stop.is_set():
                return
            now = time.monotonic()
            wake = min(self._next_level_check, self.protocol.next_own_due(),
                       self.liveness.deadline(self.setup_ok))
            if self.commands.active or self.commands.disable_pending:
                wake = min(wake, self._next_command_t)
            if self.link.failed:
                wake = min(wake, self.link.next_reopen)
            if wake > now and not self.commands.urgent():
                self._lock.wait(wake - now)

    def _check_device(self, now: float) -> bool:
        """Declare the device lost after its silence limit; True if now."""
        with self._lock:
            if not self.liveness.check(now, self.setup_ok):
                return False
            self._tally.count('device_losses')
            self._states.reset()
        logger.error('%s silent for %.0f ms (limit %.0f ms): device lost',
                     self.protocol.label, self.liveness.lost_after_s * 1e3,
                     self.liveness.limit_s * 1e3)
        return True

    def _restart_bus_if_due(self, now: float) -> bool:
        """Reopen a failed bus, or restart one stuck in bus-off, with the bounded back-off."""
        link = self.link
        period = self.config.reopen_period_s
        with self._lock:
            if (self._restarts_in_row and not link.failed
                    and link.condition is not BusCondition.BUS_OFF
                    and now - self._last_restart_mono >= period * MAX_BACKOFF_FACTOR):
                self._restarts_in_row = 0          # the bus has worked: back-off from 0
            stuck = (link.condition is BusCondition.BUS_OFF and not link.failed
                     and now - link.bus_off_since >= BUS_OFF_RESTART_S
                     and now >= link.next_reopen)
            if not ((link.failed and now >= link.next_reopen) or stuck):
                return False
            if stuck:
                self._tally.count('bus_restarts')
        if stuck:
            logger.warning('CAN bus off for %.1f s: restarting the bus', now - link.bus_off_since)
        ok = link.reopen()
        with self._lock:
            if ok and stuck:
                link.condition = BusCondition.ERROR_ACTIVE
                link.bus_off_since = now
            self._restarts_in_row = 0 if ok and not stuck else self._restarts_in_row + 1
            self._last_restart_mono = now
            self._backoff_s = period * min(2 ** self._restarts_in_row, MAX_BACKOFF_FACTOR)
            link.next_reopen = time.monotonic() + self._backoff_s
        if ok:
            self.protocol.attach(self._send, link.bus)
            with self._lock:
                self._next_command_t = 0.0
        self._check_levels()
        return True

    # --- diagnostics -------------------------------------------------------------------------
    def snapshot(self) -> DeviceSnapshot:
        """Copy the state the diagnostics need, under the lock."""
        now = time.monotonic()
        link, cmd, live = self.link, self.commands, self.liveness
        with self._lock:
            return DeviceSnapshot(
                config=self.config, label=self.protocol.label, now=now,
                counters=self._tally.copy(),
                recent=self._tally.recent(now, self.config.fault_hold_s),
                closed=self._closed, active=cmd.active, bus=link.snapshot(),
                bus_problem=self.protocol.bus_problem(),
                setup_state=self.setup_state, setup_ok=self.setup_ok,
                device_lost=live.lost, lost_after_s=live.lost_after_s,
                device_age_s=live.age_s(now), liveness_limit_s=live.limit_s,
                next_restart_in_s=max(0.0, link.next_reopen - now),
                restarts_in_row=self._restarts_in_row, restart_backoff_s=self._backoff_s,
                faults=tuple(self.protocol.faults()), device_values=self.protocol.describe(),
                duty=0.0 if cmd.watchdog_tripped else cmd.duty, pwm_frequency_hz=cmd.pwm_hz,
                watchdog_tripped=cmd.watchdog_tripped, last_command_note=cmd.last_command_note)

    def report(self) -> list[StatusReport]:
        """The driver's diagnostics now: CAN bus, device, commands, faults."""
        return diagnose_device(self.snapshot())
