"""The driver core for a device protocol (CANopen, J1939, DBC): bus, threads, watchdog.

:class:`DeviceDriverCore` has the public face of
:class:`~valve_driver_pkg.driver.core.CanDriverCore` (open, activate, deactivate, close,
set_command, report), so the node drives either. It composes

* :class:`~valve_driver_pkg.driver.bus_link.BusLink`: the bus, the receive thread, the bus
  condition (error frames and python-can's bus state);
* a :class:`~valve_driver_pkg.devices.base.DeviceProtocol`: frames in and out, set-up;
* :class:`CommandState`: the host's command, clamping, the command watchdog.

The **I/O thread** sends the command frames (at once on a change, then every
``protocol.command_period_s``) and the protocol's own frames (heartbeat), judges the
device's liveness (silent for :data:`~valve_driver_pkg.devices.base.LIVENESS_PERIODS` of its
periods: lost), sets a device that asked for it up again on a **set-up thread**, and
restarts a failed or bus-off bus with a bounded back-off (``reopen_period_s`` doubled per
failed attempt, at most :data:`MAX_BACKOFF_FACTOR` times). A reading from the device
becomes a :class:`~valve_model_pkg.model.sample.ValveSample` handed to ``on_state`` on the
receive thread, only while active and only from a live device: nothing stale is published.

One lock (a ``threading.Condition`` over an ``RLock``) guards all state; bus I/O and
callbacks run outside it.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.devices.base import LIVENESS_PERIODS, DeviceProtocol, DeviceReading
from valve_driver_pkg.devices.commands import CommandState
from valve_driver_pkg.devices.derived import DerivedOpening
from valve_driver_pkg.devices.diagnostics import DeviceSnapshot, diagnose_device
from valve_driver_pkg.driver.bus_link import BusLink, raise_thread_priority
from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.driver.core import ClearResult
from valve_driver_pkg.driver.diagnostics import Level, StatusReport, Tally, overall_level
from valve_driver_pkg.driver.frame_log import FrameLog
from valve_driver_pkg.driver.receive import MassFlowFunction
from valve_driver_pkg.driver.transmit import CommandResult
from valve_driver_pkg.errors import DeviceError
from valve_driver_pkg.protocol.error_frames import BusCondition
from valve_model_pkg.model.averaging import PeriodAverager
from valve_model_pkg.model.sample import ValveSample

__all__ = ['DeviceDriverCore', 'MAX_BACKOFF_FACTOR']

logger = logging.getLogger(__name__)

#: The I/O thread re-evaluates the diagnostic levels at least this often [s].
_LEVEL_CHECK_S = 0.05
#: A bus restart waits ``reopen_period_s * 2**k``, at most this factor times.
MAX_BACKOFF_FACTOR = 16
#: A bus-off lasting this long without the interface restarting itself: the driver
#: closes and reopens the bus [s].
_BUS_OFF_RESTART_S = 0.2
#: How long one set-up may take (configure, and again after a device boot-up) [s].
_SETUP_TIMEOUT_S = 5.0


class DeviceDriverCore:
    """The driver for a device protocol without ROS. Thread-safe.

    Parameters
    ----------
    config : DriverConfig
        Bus, rates, watchdog, pressures (``protocol`` names the protocol given here).
    protocol : DeviceProtocol
    mass_flow : MassFlowFunction | None
        Orifice equation for a measured position (eq. 12); NaN flow without either.
    on_state : callable | None
        ``on_state(ValveSample)`` on the receive thread, per device reading while active.
    on_diagnostics_changed : callable | None
        Called (driver thread) when a diagnostic level changes.
    bus_factory : callable
        ``bus_factory(interface, channel, bitrate, connect_timeout)``.
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
        self.config = config
        self._derived = derived
        self.protocol = protocol
        self._mass_flow = mass_flow
        self._on_state = on_state
        self._on_diag = on_diagnostics_changed
        self._setup_timeout_s = setup_timeout_s
        self._lock = threading.Condition(threading.RLock())
        self._stop = threading.Event()
        self._tally = Tally()
        self._closed = True
        self._levels: tuple[Level, ...] = ()
        self._io_thread: threading.Thread | None = None
        self._setup_thread: threading.Thread | None = None
        self.link = BusLink(config, self._lock, self._tally, self._stop, self._on_frame,
                            self._check_levels, bus_factory)
        self.commands = CommandState(config, self._lock, self._tally)
        self.started = False            # activated since open: the protocol's own frames run
        self.setup_state = 'not set up'
        self.setup_ok = False
        self.device_lost = False
        self.lost_after_s = 0.0
        self.last_device_mono: float | None = None
        self._opened_mono = 0.0
        self._next_setup = math.inf
        self._backoff_k = 0
        self._next_command_t = 0.0
        self._averager: PeriodAverager | None = None
        self._last_position: tuple[float, float] | None = None
        self.readings = 0

    # --- lifecycle ---------------------------------------------------------------------------
    def open(self) -> None:
        """Open the bus, set the device up, start the I/O thread.

        Raises
        ------
        BusOpenError
            No bus; nothing is left open.
        DeviceSetupError, SdoAbortError
            The device did not answer or refused its set-up; the bus is closed again.
        """
        if not self._closed:
            return
        self._stop.clear()
        self.link.open()
        if self.config.log_frames_file:
            self.link.frame_log = FrameLog(self.config.log_frames_file, self.config.channel)
        self.protocol.attach(self._send, self.link.bus)
        with self._lock:
            self._closed = False
            self._opened_mono = time.monotonic()
        self._io_thread = threading.Thread(target=self._io_loop, name='valve_device_io',
                                           daemon=True)
        self._io_thread.start()
        try:
            self._run_setup()
        except (DeviceError, OSError) as err:
            self.close()
            raise err
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
            self._lock.notify_all()

    def deactivate(self, timeout_s: float = 0.2) -> bool:
        """Send duty 0 with the output disabled once, wait for it, stop commanding.

        Returns
        -------
        bool
            True if the duty-0 frames went out within ``timeout_s``.
        """
        with self._lock:
            if not self.commands.deactivate():
                return True
            self._lock.notify_all()
            deadline = time.monotonic() + timeout_s
            while (self.commands.disable_pending and not self._closed
                   and time.monotonic() < deadline):
                self._lock.wait(deadline - time.monotonic())
            return not self.commands.disable_pending

    def close(self) -> None:
        """Stop the threads, release the protocol, close the bus; safe twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self.commands.active = False
            self.started = False
            self._stop.set()
            self._lock.notify_all()
        for thread in (self._io_thread, self._setup_thread):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=_SETUP_TIMEOUT_S)
        self._io_thread = self._setup_thread = None
        self.protocol.close()
        self.link.close()
        log, self.link.frame_log = self.link.frame_log, None
        if log is not None:
            log.close()

    @property
    def is_open(self) -> bool:
        return not self._closed

    @property
    def is_active(self) -> bool:
        return self.commands.active

    # --- inputs ------------------------------------------------------------------------------
    def set_command(self, duty: float, pwm_frequency_hz: float = 0.0, age_s: float = 0.0,
                    sequence: int | None = None, source: str = '') -> CommandResult:
        """See :meth:`CommandState.set_command`; wakes the I/O thread."""
        return self.commands.set_command(duty, pwm_frequency_hz, age_s, sequence, source)

    def set_pressures(self, supply_pa: float | None = None,
                      output_pa: float | None = None) -> bool:
        """The port pressures (gauge Pa) for the derived mass flow; non-finite: False."""
        return self.commands.set_pressures(supply_pa, output_pa)

    def set_drive_mode(self, mode: str) -> str:
        """Device protocols have no drive mode: the device's own configuration holds it."""
        logger.info('drive_mode %s ignored: protocol %s has no drive mode', mode,
                    self.protocol.name)
        return 'normal'

    @property
    def drive_mode(self) -> str:
        return 'normal'

    def clear_faults(self, timeout_s: float = 1.0) -> ClearResult:
        """Faults of these devices clear at the device (EMCY/DM1 report their end)."""
        active = tuple(f.text for f in self.protocol.faults())
        return ClearResult(not active, (), active,
                           f'protocol {self.protocol.name}: faults clear at the device; '
                           f'active: {", ".join(active) or "nothing"}')

    @property
    def command(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` the driver sends (0 while the watchdog holds)."""
        return self.commands.command

    @property
    def counters(self) -> dict[str, int]:
        with self._lock:
            return self._tally.copy()

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
        running = self._setup_thread is not None and self._setup_thread.is_alive()
        if running:
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
    def _on_frame(self, msg: can.Message) -> None:
        outcome = self.protocol.on_frame(msg)
        if not outcome.from_device:
            return
        now = time.monotonic()
        with self._lock:
            self.last_device_mono = now
            self._tally.count('device_frames')
            self.link.note_valid_traffic()
            back = self.device_lost
            if back:
                self.device_lost = False
            active = self.commands.active
        if back:
            logger.info('%s is back', self.protocol.label)
            self._check_levels()
        if outcome.reading is not None and active:
            self._publish(outcome.reading)

    def _publish(self, reading: DeviceReading) -> None:
        with self._lock:
            self.readings += 1
            duty_sent, pwm_hz = self.commands.sent
            supply, output = self.commands.supply_pa, self.commands.output_pa
            now = time.monotonic()
            freq = pwm_hz if self.protocol.sends_pwm_frequency else self.config.pwm_frequency_hz
            duty = reading.duty if math.isfinite(reading.duty) else duty_sent
            position, velocity, avg = self._measured_position(reading.spool_position_m, now,
                                                              freq)
        measured = math.isfinite(position)
        if not measured and self._derived is not None:
            position = avg = self._derived.position_avg_m(duty, freq, supply)
        flow = (self._mass_flow(avg, supply, output)
                if self._mass_flow is not None and math.isfinite(avg) else math.nan)
        if self._on_state is not None:
            self._on_state(ValveSample(
                t_s=time.time(), coil_voltage_v=reading.coil_voltage_v,
                coil_current_a=reading.coil_current_a, spool_position_m=position,
                spool_velocity_m_s=velocity, position_avg_m=avg, mass_flow_kg_s=flow,
                duty=duty,
                pwm_frequency_hz=freq if self.protocol.sends_pwm_frequency else math.nan,
                supply_pressure_pa=supply, output_pressure_pa=output,
                position_measured=measured))

    def _measured_position(self, position: float, now: float,
                           pwm_hz: float) -> tuple[float, float, float]:
        """``(position, velocity, period mean)`` of a reported position; NaN if none. Lock held."""
        if not math.isfinite(position):
            return math.nan, math.nan, math.nan
        last = self._last_position
        velocity = ((position - last[1]) / (now - last[0])
                    if last is not None and now > last[0] else 0.0)
        self._last_position = (now, position)
        if self._averager is None:
            self._averager = PeriodAverager(1.0 / pwm_hz, t0_s=now)
        else:
            self._averager.set_period(1.0 / pwm_hz)
        return position, velocity, self._averager.update(now, position)

    # --- I/O thread --------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> bool:
        sent = self.link.send(msg)
        if sent:
            with self._lock:
                self._tally.count('frames_sent')
        return sent

    def _io_loop(self) -> None:
        raise_thread_priority(self.config.io_nice, 'I/O', self.config.io_realtime_priority)
        next_level_check = 0.0
        while not self._stop.is_set():
            try:
                now = time.monotonic()
                if self._restart_bus_if_due(now):
                    continue
                changed = self._check_device(now)
                changed |= self.commands.check_watchdog(now)
                if changed:
                    self._check_levels()
                self._maybe_start_setup(now)
                self._send_due(now)
                if now >= next_level_check:
                    self.link.poll_state()
                    self._check_levels()
                    next_level_check = now + _LEVEL_CHECK_S
                self._wait(next_level_check)
            except Exception:   # noqa: BLE001 - the I/O thread must survive anything
                with self._lock:
                    self._tally.count('internal_errors')
                logger.exception('unexpected error in the device I/O thread')
                self._stop.wait(0.01)

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

    def _wait(self, next_level_check: float) -> None:
        with self._lock:
            if self._stop.is_set():
                return
            now = time.monotonic()
            wake = min(next_level_check, self.protocol.next_own_due(), self._liveness_deadline())
            if self.commands.active or self.commands.disable_pending:
                wake = min(wake, self._next_command_t)
            if self.link.failed:
                wake = min(wake, self.link.next_reopen)
            if wake > now and not self.commands.urgent():
                self._lock.wait(wake - now)

    def _liveness_deadline(self) -> float:
        period = self.protocol.liveness_period_s
        if self.device_lost or not self.setup_ok or not math.isfinite(period):
            return math.inf
        ref = self.last_device_mono if self.last_device_mono is not None else self._opened_mono
        return ref + LIVENESS_PERIODS * period + 1e-4

    def _check_device(self, now: float) -> bool:
        """Declare the device lost after LIVENESS_PERIODS silent periods; True if now."""
        with self._lock:
            deadline = self._liveness_deadline()
            if now < deadline:
                return False
            ref = self.last_device_mono if self.last_device_mono is not None \
                else self._opened_mono
            self.device_lost = True
            self.lost_after_s = now - ref
            self._tally.count('device_losses')
            self._averager = None
            self._last_position = None
        logger.error('%s silent for %.0f ms (limit %d periods of %.0f ms): device lost',
                     self.protocol.label, self.lost_after_s * 1e3, LIVENESS_PERIODS,
                     self.protocol.liveness_period_s * 1e3)
        return True

    def _restart_bus_if_due(self, now: float) -> bool:
        """Reopen a failed bus, or restart one stuck in bus-off, with a bounded back-off."""
        link = self.link
        with self._lock:
            stuck = (link.condition is BusCondition.BUS_OFF and not link.failed
                     and now - link.bus_off_since >= _BUS_OFF_RESTART_S
                     and now >= link.next_reopen)
            due = (link.failed and now >= link.next_reopen) or stuck
        if not due:
            return False
        if stuck:
            logger.warning('CAN bus off for %.1f s: restarting the bus', now - link.bus_off_since)
            with self._lock:
                self._tally.count('bus_restarts')
        ok = link.reopen()
        with self._lock:
            if ok:
                self._backoff_k = 0 if not stuck else self._backoff_k + 1
                if stuck:
                    link.condition = BusCondition.ERROR_ACTIVE if not link.failed \
                        else link.condition
                    link.bus_off_since = now
            else:
                self._backoff_k += 1
            factor = min(2 ** self._backoff_k, MAX_BACKOFF_FACTOR)
            link.next_reopen = time.monotonic() + self.config.reopen_period_s * factor
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
        link, cmd = self.link, self.commands
        with self._lock:
            last = self.last_device_mono
            return DeviceSnapshot(
                config=self.config, label=self.protocol.label, now=now,
                counters=self._tally.copy(),
                recent=self._tally.recent(now, self.config.fault_hold_s),
                closed=self._closed, active=cmd.active, bus_failed=link.failed,
                bus_error_text=link.error_text, bus_condition=link.condition,
                last_error_frame=link.last_error_frame,
                bus_problem=self.protocol.bus_problem(),
                setup_state=self.setup_state, setup_ok=self.setup_ok,
                device_lost=self.device_lost, lost_after_s=self.lost_after_s,
                device_age_s=math.inf if last is None else now - last,
                liveness_period_s=self.protocol.liveness_period_s,
                faults=tuple(self.protocol.faults()), device_values=self.protocol.describe(),
                duty=cmd.command[0], pwm_frequency_hz=cmd.pwm_hz,
                watchdog_tripped=cmd.watchdog_tripped, last_command_note=cmd.last_note)

    def report(self) -> list[StatusReport]:
        """The driver's diagnostics now: CAN bus, device, commands, faults."""
        return diagnose_device(self.snapshot())

    def overall_level(self) -> Level:
        return overall_level(self.report())

    def _check_levels(self) -> None:
        levels = tuple(r.level for r in self.report())
        with self._lock:
            changed, self._levels = levels != self._levels, levels
        if changed and self._on_diag is not None:
            try:
                self._on_diag()
            except Exception:   # noqa: BLE001 - a callback must not stop a driver thread
                logger.exception('diagnostics callback failed')
