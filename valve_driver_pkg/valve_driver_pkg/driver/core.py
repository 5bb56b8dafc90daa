"""The CAN driver's logic without ROS: bus, threads, watchdog, fault detection, diagnostics.

:class:`CanDriverCore` owns the bus and two threads; nothing it does blocks its caller:

* the **receive thread** is a ``can.Notifier`` with a ``can.Listener``: each frame is
  checked and decoded, telemetry becomes a :class:`StateSample` handed to ``on_state``
  (called on that thread; the ROS node publishes from it, ``rcl_publish`` being
  thread-safe);
* the **I/O thread** sends ``ValveCommand`` (at once on a new command and every
  ``1/command_rate_hz``) and ``ValvePressure``, runs the duty-command watchdog, declares
  the telemetry lost ``telemetry_timeout_periods`` after the last valid frame, and closes
  and reopens a failed bus every ``reopen_period_s`` until it is back. Whenever a
  diagnostic level changes it calls ``on_diagnostics_changed`` at once.

``set_command`` and ``set_pressures`` only store values and wake the I/O thread.

What is measured and what is derived (see the package README):

====================  ==================================================================
coil current/voltage  measured: ``ValveTelemetry``, quantised 0.2 mA / 10 mV
spool position        measured: the controller's estimate (``PositionValid``), 10 nm
spool velocity        derived: difference of consecutive positions / telemetry period
position average      measured: ``ValvePeriod`` (the controller's average over the last
                      complete PWM period); derived if the controller sends none: the
                      driver's trapezoidal moving average of the telemetry positions
mass flow             derived: eq. (12) (``orifice_mass_flow``) from the average position
duty, PWM frequency   measured: in force at the controller (``ValvePeriod``); without it the
                      last command sent (duty 0 while the controller reports ``Enabled=0``)
pressures             the driver's inputs (parameters or pressure topics), also sent to
                      the controller in ``ValvePressure``
====================  ==================================================================
"""
from __future__ import annotations

import enum
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import can

from valve_driver_pkg.canbus.factory import open_bus
from valve_driver_pkg.driver.averaging import PeriodAverager
from valve_driver_pkg.errors import BusOpenError, FrameRejected, ProtocolEncodeError
from valve_driver_pkg.protocol.codec import (COMMAND, CONTROL, PERIOD, PRESSURE, STATUS,
                                             TELEMETRY, CounterCheck, CounterTracker,
                                             RejectReason, ValveCodec)
from valve_driver_pkg.protocol.error_frames import BusCondition, parse_error_frame

__all__ = ['DriverConfig', 'CanDriverCore', 'StateSample', 'CommandResult', 'Level',
           'StatusReport', 'MassFlowFunction']

logger = logging.getLogger(__name__)

#: Telemetry losses are logged at most this often (the diagnostics count every one) [s].
_LOG_INTERVAL_S = 5.0

#: ``f(position_avg_m, supply_pa, output_pa) -> kg/s`` (gauge pressures).
MassFlowFunction = Callable[[float, float, float], float]


class Level(enum.IntEnum):
    """Diagnostic levels, the values of diagnostic_msgs/DiagnosticStatus."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class DriverConfig:
    """Settings of the driver core (the node fills it from its parameters).

    Attributes
    ----------
    interface, channel : str
        python-can interface (or ``tcp_loopback``) and channel.
    bitrate : int
        Bit rate for interfaces that set it [bit/s].
    node_id : int
        Controller node id.
    dbc_path : str
        DBC file; empty = the shipped one.
    command_rate_hz : float
        Refresh rate of ``ValveCommand`` [Hz] (also sent at once on a new command).
    command_timeout_s : float
        Duty-command watchdog: no valid command for this long commands duty 0; 0 = off.
    telemetry_period_s : float
        Expected ``ValveTelemetry`` period [s].
    telemetry_timeout_periods : float
        Telemetry is declared lost (ERROR) this many periods after the last valid frame.
    status_timeout_s : float
        Heartbeat (``ValveStatus``) missing for this long gives a WARN [s].
    pressure_rate_hz : float
        Refresh rate of ``ValvePressure`` [Hz].
    fault_hold_s : float
        A rejected frame, clamped command or bus warning keeps its WARN this long [s].
    reopen_period_s : float
        Pause between attempts to reopen a failed bus [s].
    open_timeout_s : float
        How long opening may wait for the bus (``tcp_loopback``: for the hub) [s].
    frozen_counter_limit : int
        Consecutive repeated telemetry counters that make the counter "frozen" (ERROR).
    pwm_frequency_hz : float
        PWM frequency in force until a command sets one [Hz].
    max_pwm_frequency_hz : float
        Commands above it are clamped to it [Hz] (the DBC's limit if lower).
    """

    interface: str = 'virtual'
    channel: str = 'valve0'
    bitrate: int = 500_000
    node_id: int = 0
    dbc_path: str = ''
    command_rate_hz: float = 100.0
    command_timeout_s: float = 0.5
    telemetry_period_s: float = 0.001
    telemetry_timeout_periods: float = 2.5
    status_timeout_s: float = 0.35
    pressure_rate_hz: float = 10.0
    fault_hold_s: float = 1.0
    reopen_period_s: float = 0.5
    open_timeout_s: float = 5.0
    frozen_counter_limit: int = 3
    pwm_frequency_hz: float = 50.0
    max_pwm_frequency_hz: float = 1000.0


@dataclass(slots=True)
class StateSample:
    """One valve state from one telemetry frame (fields as valve_msgs/ValveState, SI)."""

    stamp_s: float                 # wall-clock receive time [s since the epoch]
    coil_voltage_v: float
    coil_current_a: float
    spool_position_m: float
    spool_velocity_m_s: float
    position_avg_m: float
    mass_flow_kg_s: float
    duty: float
    pwm_frequency_hz: float
    supply_pressure_pa: float
    output_pressure_pa: float
    position_measured: bool
    receive_perf_s: float = 0.0    # perf_counter() when the frame arrived (latency figures)


@dataclass(frozen=True, slots=True)
class CommandResult:
    """What ``set_command`` did with a duty command."""

    accepted: bool
    duty: float
    pwm_frequency_hz: float
    clamped: bool
    message: str


@dataclass(slots=True)
class StatusReport:
    """One diagnostic status (ROS-free mirror of diagnostic_msgs/DiagnosticStatus)."""

    name: str
    level: Level
    message: str
    values: dict = field(default_factory=dict)


class _RxListener(can.Listener):
    """Notifier callback: hands frames to the core; reports receive errors."""

    def __init__(self, core: CanDriverCore) -> None:
        self._core = core

    def on_message_received(self, msg: can.Message) -> None:
        try:
            self._core._on_frame(msg)
        except Exception:   # noqa: BLE001 - nothing a frame does may stop the receive thread
            self._core._count('internal_errors')
            logger.exception('unexpected error handling a frame; frame dropped')

    def on_error(self, exc: Exception) -> None:
        self._core._on_bus_error(exc)


class CanDriverCore:
    """The driver without ROS. Thread-safe; see the module docstring for the threads.

    Parameters
    ----------
    config : DriverConfig
    mass_flow : MassFlowFunction | None
        Orifice equation for the derived mass flow; ``None`` reports 0.
    on_state : callable | None
        ``on_state(StateSample)``, called on the receive thread for every valid telemetry
        frame while the driver is active.
    on_diagnostics_changed : callable | None
        ``on_diagnostics_changed()``, called (on a driver thread) when a level changes.
    bus_factory : callable
        ``bus_factory(interface, channel, bitrate, connect_timeout)``; tests inject buses.
    """

    def __init__(self, config: DriverConfig, mass_flow: MassFlowFunction | None = None,
                 on_state: Callable[[StateSample], None] | None = None,
                 on_diagnostics_changed: Callable[[], None] | None = None,
                 bus_factory: Callable[..., can.BusABC] = open_bus,
                 supply_pressure_pa: float = 400_000.0, output_pressure_pa: float = 0.0) -> None:
        self.config = config
        self.codec = ValveCodec(config.node_id, config.dbc_path or None)
        self._mass_flow = mass_flow
        self._on_state = on_state
        self._on_diag = on_diagnostics_changed
        self._bus_factory = bus_factory
        f_lo, f_hi = self.codec.signal_range(COMMAND, 'PwmFrequency')
        self._f_min = f_lo
        self._f_max = min(f_hi, config.max_pwm_frequency_hz)
        self._p_lo, self._p_hi = self.codec.signal_range(PRESSURE, 'SupplyPressure')
        self._lock = threading.RLock()
        self._wake = threading.Condition(self._lock)
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._io_thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = True
        self._active = False
        self._bus_failed = False
        self._bus_error_text = ''
        self._next_reopen = 0.0
        # command state
        self._duty = 0.0
        self._pwm_hz = min(max(config.pwm_frequency_hz, self._f_min), self._f_max)
        self._command_dirty = False
        self._command_gen = 0          # +1 per change; a send clears "dirty" only if unchanged
        self._pressure_gen = 0
        self._last_command_mono: float | None = None
        self._watchdog_tripped = False
        self._tx_counter = 0
        self._pressure_counter = 0
        self._next_command_t = 0.0
        self._next_pressure_t = 0.0
        self._pressure_dirty = True
        self._supply_pa = float(supply_pressure_pa)
        self._output_pa = float(output_pressure_pa)
        self._send_disable = False
        self._sent_enable = False
        self._last_sent_duty = 0.0
        self._last_command_note = ''
        # receive state
        self._telemetry_counter = CounterTracker()
        self._status_counter = CounterTracker()
        self._frozen_run = 0
        self._last_valid_telemetry: float | None = None
        self._open_mono = 0.0
        self._telemetry_lost = True
        self._lost_after_s = 0.0
        self._last_loss_log = -math.inf
        self._losses_logged = 0
        self._last_sample_t = 0.0
        self._last_position: float | None = None
        self._averager = PeriodAverager(1.0 / self._pwm_hz)
        self._controller_enabled = False
        self._period_counter = CounterTracker()
        self._period: tuple[float, float, float, float] | None = None   # avg, duty, f, mono
        self._period_fresh_s = 0.5
        self._last_status: dict | None = None
        self._last_status_mono: float | None = None
        self._bus_condition = BusCondition.ERROR_ACTIVE
        self._last_error_frame = ''
        self._last_reject = ''
        self._recent: dict[str, float] = {}
        self._rate_window = (time.monotonic(), 0)
        self._telemetry_rate_hz = 0.0
        self.counters: dict[str, int] = {
            'telemetry_frames': 0, 'period_frames': 0, 'status_frames': 0, 'host_frames': 0,
            'rejected_total': 0,
            **{f'rejected_{r.value}': 0 for r in RejectReason},
            'counter_jumps': 0, 'frames_lost': 0, 'other_node_frames': 0,
            'error_frames': 0, 'error_passive_events': 0, 'bus_off_events': 0,
            'bus_recoveries': 0, 'bus_failures': 0, 'bus_reopens': 0, 'tx_errors': 0,
            'commands_received': 0, 'commands_clamped': 0, 'commands_rejected': 0,
            'command_frames_sent': 0, 'pressure_frames_sent': 0, 'watchdog_trips': 0,
            'telemetry_losses': 0, 'internal_errors': 0,
        }
        self._levels: tuple[Level, ...] = ()

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
        self._open_bus()
        self._closed = False
        self._open_mono = time.monotonic()
        self._io_thread = threading.Thread(target=self._io_loop, name='valve_can_io',
                                           daemon=True)
        self._io_thread.start()

    def _open_bus(self) -> None:
        bus = self._bus_factory(self.config.interface, self.config.channel, self.config.bitrate,
                                connect_timeout=self.config.open_timeout_s)
        try:
            notifier = can.Notifier(bus, [_RxListener(self)], timeout=0.1)
        except Exception as err:
            bus.shutdown()
            raise BusOpenError(f'cannot start receiving on {self.config.interface}:'
                               f'{self.config.channel}: {err}') from err
        with self._lock:
            self._bus, self._notifier = bus, notifier
            self._bus_failed = False
            self._telemetry_counter.reset()
            self._status_counter.reset()
            self._period_counter.reset()

    def _close_bus(self) -> None:
        with self._lock:
            bus, notifier = self._bus, self._notifier
            self._bus, self._notifier = None, None
        if notifier is not None:
            notifier.stop(timeout=1.0)
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as err:
                logger.debug('bus shutdown: %s', err)

    def activate(self) -> None:
        """Start sending commands; the command starts at duty 0 until one arrives."""
        with self._wake:
            self._duty = 0.0
            self._last_command_mono = None
            self._watchdog_tripped = False
            self._active = True
            self._send_disable = False
            self._mark_command_dirty()
            self._mark_pressure_dirty()
            self._wake.notify()

    def deactivate(self, timeout_s: float = 0.2) -> bool:
        """Command duty 0 (output disabled), wait until that frame is sent, stop sending.

        Returns
        -------
        bool
            True if the duty-0 frame went out within ``timeout_s``.
        """
        with self._wake:
            if not self._active:
                return True
            self._active = False
            self._duty = 0.0
            self._send_disable = True
            self._wake.notify()
            deadline = time.monotonic() + timeout_s
            while self._send_disable and time.monotonic() < deadline and not self._closed:
                self._wake.wait(deadline - time.monotonic())
            return not self._send_disable

    def close(self) -> None:
        """Stop the threads and close the bus; safe to call more than once."""
        with self._wake:
            if self._closed:
                return
            self._closed = True
            self._active = False
            self._stop.set()
            self._wake.notify_all()
        if self._io_thread is not None and self._io_thread is not threading.current_thread():
            self._io_thread.join(timeout=2.0)
        self._io_thread = None
        self._close_bus()

    def _mark_command_dirty(self) -> None:
        self._command_dirty = True
        self._command_gen += 1

    def _mark_pressure_dirty(self) -> None:
        self._pressure_dirty = True
        self._pressure_gen += 1

    @property
    def is_open(self) -> bool:
        return not self._closed

    @property
    def is_active(self) -> bool:
        return self._active

    # --- inputs ------------------------------------------------------------------------------
    def set_command(self, duty: float, pwm_frequency_hz: float = 0.0) -> CommandResult:
        """Take a duty command (DutyCommand semantics); never raises, never sends raw.

        Non-finite values and a negative frequency are rejected (the last valid command
        stays); a duty outside [0, 1] and a frequency outside the protocol's range are
        clamped. Frequency 0 keeps the frequency in force. Both are counted and reported.
        """
        duty = float(duty)
        freq = float(pwm_frequency_hz)
        with self._wake:
            self.counters['commands_received'] += 1
            if not (math.isfinite(duty) and math.isfinite(freq)) or freq < 0.0:
                self.counters['commands_rejected'] += 1
                self._mark('command_rejected')
                note = (f'duty command rejected: duty={duty!r}, pwm_frequency={freq!r} '
                        '(not finite or negative frequency); keeping the last valid command')
                self._last_command_note = note
                return CommandResult(False, self._duty, self._pwm_hz, False, note)
            notes = []
            if freq == 0.0:
                freq = self._pwm_hz
            elif not self._f_min <= freq <= self._f_max:
                clamped_f = min(max(freq, self._f_min), self._f_max)
                notes.append(f'pwm_frequency {freq!r} Hz outside [{self._f_min:g}, '
                             f'{self._f_max:g}] clamped to {clamped_f:g}')
                freq = clamped_f
            if not 0.0 <= duty <= 1.0:
                clamped_d = min(max(duty, 0.0), 1.0)
                notes.append(f'duty {duty!r} outside [0, 1] clamped to {clamped_d:g}')
                duty = clamped_d
            if notes:
                self.counters['commands_clamped'] += 1
                self._mark('command_clamped')
                self._last_command_note = '; '.join(notes)
            self._duty, self._pwm_hz = duty, freq
            self._last_command_mono = time.monotonic()
            if self._watchdog_tripped:
                logger.info('duty commands are back; watchdog released')
            self._watchdog_tripped = False
            self._mark_command_dirty()
            self._wake.notify()
            return CommandResult(True, duty, freq, bool(notes), '; '.join(notes))

    def set_pressures(self, supply_pa: float | None = None,
                      output_pa: float | None = None) -> bool:
        """Set the port pressures (gauge Pa); a non-finite value is rejected (False)."""
        with self._wake:
            for value in (supply_pa, output_pa):
                if value is not None and not math.isfinite(value):
                    return False
            if supply_pa is not None:
                self._supply_pa = float(supply_pa)
            if output_pa is not None:
                self._output_pa = float(output_pa)
            self._mark_pressure_dirty()
            self._wake.notify()
            return True

    @property
    def command(self) -> tuple[float, float]:
        """``(duty, pwm_frequency_hz)`` the driver sends (0 while the watchdog holds)."""
        with self._lock:
            return (0.0 if self._watchdog_tripped else self._duty), self._pwm_hz

    # --- receive thread ----------------------------------------------------------------------
    def _count(self, key: str, n: int = 1) -> None:
        self.counters[key] = self.counters.get(key, 0) + n

    def _mark(self, key: str) -> None:
        self._recent[key] = time.monotonic()

    def _reject(self, reason: str, detail: str) -> None:
        self.counters['rejected_total'] += 1
        self.counters[f'rejected_{reason}'] += 1
        self._last_reject = detail
        self._mark('rejected_' + reason)
        logger.debug('frame rejected: %s', detail)

    def _on_frame(self, msg: can.Message) -> None:
        receive_perf = time.perf_counter()
        if msg.is_error_frame:
            self._on_error_frame(msg)
            return
        found = self.codec.classify(msg.arbitration_id)
        if found is not None and found[1] != self.config.node_id:
            self.counters['other_node_frames'] += 1   # another valve on the same bus
            return
        if found is not None and found[0] in (COMMAND, PRESSURE, CONTROL):
            self.counters['host_frames'] += 1   # another host or a test tool: not for us
            return
        try:
            frame = self.codec.decode(msg)
        except FrameRejected as err:
            self._reject(err.reason, err.detail)
            return
        if frame.name == TELEMETRY:
            self._on_telemetry(frame.signals, frame.counter, receive_perf)
        elif frame.name == PERIOD:
            self._on_period(frame.signals, frame.counter)
        elif frame.name == STATUS:
            self._on_status(frame.signals, frame.counter)

    def _on_period(self, signals: dict, counter: int) -> None:
        if self._period_counter.check(counter) is CounterCheck.FROZEN:
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValvePeriod counter stuck at {counter}')
            return
        self.counters['period_frames'] += 1
        self._period = (float(signals['PositionAverage']), float(signals['DutyActive']),
                        float(signals['PwmFrequencyActive']), time.monotonic())

    def _on_error_frame(self, msg: can.Message) -> None:
        info = parse_error_frame(msg)
        self.counters['error_frames'] += 1
        self._last_error_frame = info.text
        self._mark('error_frame')
        previous = self._bus_condition
        condition = info.condition
        if condition is BusCondition.BUS_OFF:
            if previous is not BusCondition.BUS_OFF:
                self.counters['bus_off_events'] += 1
            self._bus_condition = BusCondition.BUS_OFF
        elif condition is BusCondition.ERROR_PASSIVE:
            if previous is not BusCondition.ERROR_PASSIVE:
                self.counters['error_passive_events'] += 1
            if previous is not BusCondition.BUS_OFF:
                self._bus_condition = BusCondition.ERROR_PASSIVE
        elif condition is BusCondition.WARNING:
            if previous is BusCondition.ERROR_ACTIVE:
                self._bus_condition = BusCondition.WARNING
        elif condition in (BusCondition.RESTARTED, BusCondition.ERROR_ACTIVE):
            if previous is not BusCondition.ERROR_ACTIVE:
                self.counters['bus_recoveries'] += 1
            self._bus_condition = BusCondition.ERROR_ACTIVE
        if self._bus_condition is not previous:
            logger.warning('CAN bus %s: %s', self._bus_condition.value, info.text)
            self._check_levels()

    def _on_status(self, signals: dict, counter: int) -> None:
        check = self._status_counter.check(counter)
        if check is CounterCheck.FROZEN:
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValveStatus counter stuck at {counter}')
            return
        self.counters['status_frames'] += 1
        self._last_status = signals
        self._last_status_mono = time.monotonic()

    def _on_telemetry(self, signals: dict, counter: int, receive_perf: float) -> None:
        now = time.monotonic()
        check = self._telemetry_counter.check(counter)
        period = self.config.telemetry_period_s
        if check is CounterCheck.FROZEN:
            self._frozen_run += 1
            self._reject(RejectReason.COUNTER_FROZEN.value,
                         f'ValveTelemetry counter stuck at {counter} '
                         f'({self._frozen_run} frames)')
            if self._frozen_run == self.config.frozen_counter_limit:
                self._check_levels()
            return
        self._frozen_run = 0
        was_lost = self._telemetry_lost
        if check is CounterCheck.JUMP:
            self.counters['counter_jumps'] += 1
            self.counters['frames_lost'] += self._telemetry_counter.lost
            self._mark('counter_jump')
        steps = 1 + self._telemetry_counter.lost
        if was_lost or check is CounterCheck.FIRST:
            self._averager.reset()
            self._last_position = None
            steps = 1
        self.counters['telemetry_frames'] += 1
        self._last_valid_telemetry = now
        if self._bus_condition is BusCondition.BUS_OFF:
            # Frames flow again: the bus is back even if no "restarted" frame came.
            self._bus_condition = BusCondition.ERROR_ACTIVE
            self.counters['bus_recoveries'] += 1
        if was_lost:
            self._telemetry_lost = False
            if self._losses_logged == self.counters['telemetry_losses']:
                logger.info('telemetry is back')   # only after a loss that was logged
            self._check_levels()
        t = self._last_sample_t + steps * period
        self._last_sample_t = t
        position = float(signals['SpoolPosition'])
        previous = self._last_position
        velocity = 0.0 if previous is None else (position - previous) / (steps * period)
        self._last_position = position
        with self._lock:
            duty_cmd, pwm_hz = self._last_sent_duty, self._pwm_hz
            supply, output = self._supply_pa, self._output_pa
        window = 1.0 / pwm_hz
        if window != self._averager.window_s:
            self._averager.set_window(window)
        average = self._averager.add(t, position)
        enabled = bool(signals['Enabled'])
        self._controller_enabled = enabled
        duty = duty_cmd if enabled else 0.0
        period = self._period
        if period is not None and now - period[3] <= self._period_fresh_s:
            average, duty, pwm_hz = period[0], period[1], period[2] or pwm_hz
        flow = self._mass_flow(average, supply, output) if self._mass_flow else 0.0
        on_state = self._on_state
        if on_state is not None and self._active:
            on_state(StateSample(
                stamp_s=time.time(), coil_voltage_v=float(signals['CoilVoltage']),
                coil_current_a=float(signals['CoilCurrent']), spool_position_m=position,
                spool_velocity_m_s=velocity, position_avg_m=average, mass_flow_kg_s=flow,
                duty=duty, pwm_frequency_hz=pwm_hz,
                supply_pressure_pa=supply, output_pressure_pa=output,
                position_measured=bool(signals['PositionValid']),
                receive_perf_s=receive_perf))

    def _on_bus_error(self, exc: Exception) -> None:
        with self._wake:
            first = not self._bus_failed
            self._bus_failed = True
            self._bus_error_text = str(exc)
            self._wake.notify()
        if first:
            self.counters['bus_failures'] += 1
            logger.error('CAN bus failed: %s; reopening every %.1f s', exc,
                         self.config.reopen_period_s)
            self._check_levels()
        # The notifier calls recv() again at once; do not spin on a dead bus.
        self._stop.wait(0.05)

    # --- I/O thread --------------------------------------------------------------------------
    def _io_loop(self) -> None:
        cfg = self.config
        command_period = 1.0 / cfg.command_rate_hz
        pressure_period = 1.0 / cfg.pressure_rate_hz
        timeout = cfg.telemetry_timeout_periods * cfg.telemetry_period_s
        next_level_check = 0.0
        while not self._stop.is_set():
            try:
                now = time.monotonic()
                if self._bus_failed and now >= self._next_reopen:
                    self._reopen()
                    continue
                self._check_telemetry(now, timeout)
                self._check_watchdog(now)
                self._send_due(now, command_period, pressure_period)
                if now >= next_level_check:
                    self._check_levels()
                    next_level_check = now + 0.05
                with self._wake:
                    if self._stop.is_set():
                        break
                    wait = min(self._next_command_t, self._next_pressure_t,
                               next_level_check) - time.monotonic()
                    if not self._telemetry_lost and self._last_valid_telemetry is not None:
                        wait = min(wait, self._last_valid_telemetry + timeout
                                   - time.monotonic() + 1e-5)
                    if self._bus_failed:
                        wait = min(wait, self._next_reopen - time.monotonic())
                    if (wait > 0.0 and not self._command_dirty and not self._send_disable
                            and not (self._pressure_dirty and self._active)):
                        self._wake.wait(wait)
            except Exception:   # noqa: BLE001 - the I/O thread must survive anything
                self._count('internal_errors')
                logger.exception('unexpected error in the CAN I/O thread')
                self._stop.wait(0.01)

    def _reopen(self) -> None:
        self._close_bus()
        self.counters['bus_reopens'] += 1
        try:
            self._open_bus_quick()
        except BusOpenError as err:
            self._next_reopen = time.monotonic() + self.config.reopen_period_s
            logger.debug('reopen failed: %s', err)
            return
        logger.info('CAN bus %s:%s reopened', self.config.interface, self.config.channel)
        with self._wake:
            self._mark_command_dirty()
            self._mark_pressure_dirty()
        self._check_levels()

    def _open_bus_quick(self) -> None:
        bus = self._bus_factory(self.config.interface, self.config.channel, self.config.bitrate,
                                connect_timeout=min(0.2, self.config.open_timeout_s))
        try:
            notifier = can.Notifier(bus, [_RxListener(self)], timeout=0.1)
        except Exception as err:
            bus.shutdown()
            raise BusOpenError(str(err)) from err
        with self._lock:
            self._bus, self._notifier = bus, notifier
            self._bus_failed = False
            self._telemetry_counter.reset()
            self._status_counter.reset()
            self._period_counter.reset()

    def _check_telemetry(self, now: float, timeout: float) -> None:
        last = self._last_valid_telemetry
        reference = last if last is not None else self._open_mono
        if not self._telemetry_lost and now - reference > timeout:
            self._telemetry_lost = True
            self._lost_after_s = now - reference
            self.counters['telemetry_losses'] += 1
            if now - self._last_loss_log >= _LOG_INTERVAL_S:
                suppressed = self.counters['telemetry_losses'] - self._losses_logged - 1
                logger.error('telemetry lost: no valid ValveTelemetry for %.2f ms (limit %.2f '
                             'ms)%s', self._lost_after_s * 1e3, timeout * 1e3,
                             f'; {suppressed} more losses since the last message'
                             if suppressed > 0 else '')
                self._last_loss_log = now
                self._losses_logged = self.counters['telemetry_losses']
            self._check_levels()

    def _check_watchdog(self, now: float) -> None:
        limit = self.config.command_timeout_s
        with self._wake:
            if (self._active and limit > 0.0 and not self._watchdog_tripped
                    and self._last_command_mono is not None
                    and now - self._last_command_mono > limit):
                self._watchdog_tripped = True
                self.counters['watchdog_trips'] += 1
                self._mark_command_dirty()
                logger.warning('watchdog: no duty command for %.3f s; valve commanded closed',
                               limit)
                trip = True
            else:
                trip = False
        if trip:
            self._check_levels()

    def _send_due(self, now: float, command_period: float, pressure_period: float) -> None:
        with self._wake:
            bus = self._bus
            send_command = (self._send_disable or
                            (self._active and (self._command_dirty
                                               or now >= self._next_command_t)))
            send_pressure = self._active and (self._pressure_dirty
                                              or now >= self._next_pressure_t)
            disabling = self._send_disable
            enable = self._active and not disabling
            duty = 0.0 if (self._watchdog_tripped or not enable) else self._duty
            freq = self._pwm_hz
            supply = min(max(self._supply_pa, self._p_lo), self._p_hi)
            output = min(max(self._output_pa, self._p_lo), self._p_hi)
            command_gen, pressure_gen = self._command_gen, self._pressure_gen
            if not self._active and not self._send_disable:
                self._next_command_t = self._next_pressure_t = now + 0.05
        if bus is None or self._bus_failed:
            return
        if send_command:
            signals = {'Duty': duty, 'PwmFrequency': freq, 'Enable': int(enable),
                       'ClearFaults': 0}
            sent = self._send(bus, COMMAND, signals, self._tx_counter)
            with self._wake:
                self._tx_counter = (self._tx_counter + 1) & 0xF
                if self._command_gen == command_gen:   # else a newer command is waiting
                    self._command_dirty = False
                self._next_command_t = now + command_period
                if sent:
                    self.counters['command_frames_sent'] += 1
                    self._last_sent_duty = duty
                    self._sent_enable = enable
                if disabling:   # only the frame built as "disable" completes deactivate()
                    self._send_disable = False
                    self._wake.notify_all()
        if send_pressure:
            signals = {'SupplyPressure': supply, 'OutputPressure': output}
            sent = self._send(bus, PRESSURE, signals, self._pressure_counter)
            with self._wake:
                self._pressure_counter = (self._pressure_counter + 1) & 0xF
                if self._pressure_gen == pressure_gen:
                    self._pressure_dirty = False
                self._next_pressure_t = now + pressure_period
                if sent:
                    self.counters['pressure_frames_sent'] += 1

    def _send(self, bus: can.BusABC, name: str, signals: dict, counter: int) -> bool:
        try:
            msg = self.codec.encode(name, signals, counter)
        except ProtocolEncodeError as err:   # clamped before: this is a bug, never send raw
            self._count('internal_errors')
            logger.error('not sent: %s', err)
            return False
        try:
            bus.send(msg, timeout=0.01)
            return True
        except can.CanError as err:
            self.counters['tx_errors'] += 1
            self._mark('tx_error')
            logger.debug('send failed: %s', err)
            return False

    # --- diagnostics -------------------------------------------------------------------------
    def _recent_keys(self, now: float) -> list[str]:
        hold = self.config.fault_hold_s
        return [k for k, t in list(self._recent.items()) if now - t <= hold]

    def _check_levels(self) -> None:
        levels = tuple(r.level for r in self.report())
        if levels != self._levels:
            self._levels = levels
            callback = self._on_diag
            if callback is not None:
                try:
                    callback()
                except Exception:   # noqa: BLE001
                    logger.exception('diagnostics callback failed')

    def report(self) -> list[StatusReport]:
        """The driver's diagnostics now: bus, telemetry, commands, controller."""
        now = time.monotonic()
        recent = set(self._recent_keys(now))
        c = dict(self.counters)
        cfg = self.config
        hw = f'{cfg.interface}:{cfg.channel} node {cfg.node_id}'

        # bus
        if self._closed:
            bus = StatusReport('CAN bus', Level.STALE, 'bus closed')
        elif self._bus_failed:
            bus = StatusReport('CAN bus', Level.ERROR,
                               f'bus failed ({self._bus_error_text}); reopening')
        elif self._bus_condition is BusCondition.BUS_OFF:
            bus = StatusReport('CAN bus', Level.ERROR, f'bus-off ({self._last_error_frame})')
        elif self._bus_condition is BusCondition.ERROR_PASSIVE:
            bus = StatusReport('CAN bus', Level.WARN,
                               f'error passive ({self._last_error_frame})')
        elif self._bus_condition is BusCondition.WARNING:
            bus = StatusReport('CAN bus', Level.WARN, f'error warning ({self._last_error_frame})')
        elif 'rejected_unknown_id' in recent or 'rejected_frame_type' in recent \
                or 'tx_error' in recent:
            bus = StatusReport('CAN bus', Level.WARN, f'bus problems: {self._last_reject}'
                               if 'tx_error' not in recent else 'send errors')
        else:
            bus = StatusReport('CAN bus', Level.OK, 'error active')
        bus.values = {'hardware': hw, 'condition': self._bus_condition.value,
                      **{k: c[k] for k in ('error_frames', 'error_passive_events',
                                           'bus_off_events', 'bus_recoveries', 'bus_failures',
                                           'bus_reopens', 'tx_errors', 'rejected_unknown_id',
                                           'rejected_frame_type', 'other_node_frames')},
                      'last_error_frame': self._last_error_frame}

        # telemetry
        last = self._last_valid_telemetry
        age = (now - last) if last is not None else math.inf
        window_start, window_count = self._rate_window
        if now - window_start >= 0.5:
            self._telemetry_rate_hz = (c['telemetry_frames'] - window_count) / (now - window_start)
            self._rate_window = (now, c['telemetry_frames'])
        limit = cfg.telemetry_timeout_periods * cfg.telemetry_period_s
        rejected_recent = sorted(k[len('rejected_'):] for k in recent
                                 if k.startswith('rejected_') and k not in
                                 ('rejected_unknown_id', 'rejected_frame_type'))
        if self._closed:
            tel = StatusReport('telemetry', Level.STALE, 'bus closed')
        elif self._telemetry_lost:
            frozen = self._frozen_run >= cfg.frozen_counter_limit
            why = (f'counter frozen at {self._telemetry_counter.last}' if frozen
                   else 'no valid ValveTelemetry')
            detail = f'; recent rejections: {", ".join(rejected_recent)}' \
                if rejected_recent else ''
            tel = StatusReport('telemetry', Level.ERROR,
                               f'telemetry stopped: {why} for {age * 1e3:.1f} ms '
                               f'(limit {limit * 1e3:.2f} ms){detail}')
        elif self._frozen_run >= cfg.frozen_counter_limit:
            tel = StatusReport('telemetry', Level.ERROR,
                               f'counter frozen at {self._telemetry_counter.last}')
        elif rejected_recent or 'counter_jump' in recent:
            what = rejected_recent + (['counter jumps'] if 'counter_jump' in recent else [])
            tel = StatusReport('telemetry', Level.WARN,
                               f'frames rejected or lost: {", ".join(what)}; last: '
                               f'{self._last_reject or "counter jump"}')
        else:
            tel = StatusReport('telemetry', Level.OK, f'{self._telemetry_rate_hz:.0f} Hz')
        period = self._period
        tel.values = {'age_s': age, 'timeout_s': limit,
                      'average_source': 'controller' if period is not None and
                      now - period[3] <= self._period_fresh_s else 'driver',
                      'lost_after_s': self._lost_after_s,
                      'rate_hz': self._telemetry_rate_hz,
                      **{k: c[k] for k in ('telemetry_frames', 'telemetry_losses',
                                           'rejected_total', 'rejected_checksum',
                                           'rejected_wrong_length', 'rejected_counter_frozen',
                                           'rejected_out_of_range', 'rejected_unknown_id',
                                           'rejected_frame_type', 'counter_jumps',
                                           'frames_lost', 'internal_errors')},
                      'last_rejection': self._last_reject}

        # commands
        duty, freq = self.command
        if self._closed:
            cmd = StatusReport('commands', Level.STALE, 'bus closed')
        elif self._watchdog_tripped:
            cmd = StatusReport('commands', Level.WARN,
                               f'watchdog: no duty command for {cfg.command_timeout_s:g} s; '
                               'valve commanded closed (duty 0)')
        elif 'command_rejected' in recent or 'command_clamped' in recent:
            cmd = StatusReport('commands', Level.WARN, self._last_command_note)
        elif not self._active:
            cmd = StatusReport('commands', Level.OK, 'inactive: not sending')
        else:
            cmd = StatusReport('commands', Level.OK, f'duty {duty:.4g} at {freq:g} Hz')
        cmd.values = {'duty': duty, 'pwm_frequency_hz': freq, 'active': self._active,
                      'watchdog_tripped': self._watchdog_tripped,
                      'command_timeout_s': cfg.command_timeout_s,
                      **{k: c[k] for k in ('commands_received', 'commands_clamped',
                                           'commands_rejected', 'command_frames_sent',
                                           'pressure_frames_sent', 'watchdog_trips')},
                      'last_command_problem': self._last_command_note}

        # controller (heartbeat)
        status = self._last_status
        hb_age = (now - self._last_status_mono) if self._last_status_mono else math.inf
        flags = sorted(k[len('Fault'):] for k, v in (status or {}).items()
                       if k.startswith('Fault') and v)
        state = int(status['ControllerState']) if status else -1
        state_name = {0: 'init', 1: 'standby', 2: 'running', 3: 'fault'}.get(state, 'unknown')
        if self._closed:
            ctl = StatusReport('controller', Level.STALE, 'bus closed')
        elif status is None or hb_age > cfg.status_timeout_s:
            ctl = StatusReport('controller', Level.WARN if status is None else Level.ERROR,
                               'no ValveStatus heartbeat' + (
                                   '' if status is None else f' for {hb_age:.2f} s'))
        elif state == 3 or 'Overcurrent' in flags or 'Internal' in flags:
            ctl = StatusReport('controller', Level.ERROR,
                               f'controller fault: {", ".join(flags) or state_name}')
        elif flags:
            ctl = StatusReport('controller', Level.WARN, f'controller reports {", ".join(flags)}')
        else:
            ctl = StatusReport('controller', Level.OK, state_name)
        ctl.values = {'state': state_name, 'fault_flags': ','.join(flags),
                      'heartbeat_age_s': hb_age, 'status_frames': c['status_frames']}
        if status:
            ctl.values.update(duty_active=status['DutyActive'],
                              pwm_frequency_active_hz=status['PwmFrequencyActive'],
                              supply_voltage_v=status['SupplyVoltage'])
        reports = [bus, tel, cmd, ctl]
        for r in reports:
            r.values.setdefault('hardware', hw)
        return reports

    def overall_level(self) -> Level:
        """Worst level of :meth:`report` (STALE counts as ERROR)."""
        worst = max((r.level for r in self.report()), default=Level.OK)
        return Level.ERROR if worst is Level.STALE else Level(worst)

    @staticmethod
    def default_dbc_path() -> Path:
        from valve_driver_pkg.protocol.codec import default_dbc_path
        return default_dbc_path()
