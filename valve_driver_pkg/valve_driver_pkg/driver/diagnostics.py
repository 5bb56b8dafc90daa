"""Diagnostics of the driver: a frozen snapshot in, four statuses out, nothing changed.

:class:`DriverSnapshot` is what the driver core copies out under its lock;
:func:`diagnose` turns it into the four statuses (CAN bus, telemetry, commands,
controller) without touching the driver. :class:`Tally` holds the counters and the
"recent event" marks the statuses are built from.
"""
from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from valve_driver_pkg.driver.config import DriverConfig
from valve_driver_pkg.protocol.codec import DriveMode, RejectReason
from valve_driver_pkg.protocol.error_frames import BusCondition

__all__ = ['Level', 'StatusReport', 'Tally', 'COUNTER_KEYS', 'LATCHED_FLAGS', 'DriverSnapshot',
           'CoreSnapshot', 'BusSnapshot', 'BUS_COUNTERS', 'diagnose', 'overall_level',
           'fault_flags']


class Level(enum.IntEnum):
    """Diagnostic levels, the values of diagnostic_msgs/DiagnosticStatus."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(slots=True)
class StatusReport:
    """One diagnostic status (ROS-free mirror of diagnostic_msgs/DiagnosticStatus)."""

    name: str
    level: Level
    message: str
    values: dict = field(default_factory=dict)


#: Every counter of the driver, in the order the diagnostics list them.
COUNTER_KEYS = (
    'telemetry_frames', 'period_frames', 'status_frames', 'host_frames', 'rejected_total',
    *(f'rejected_{r.value}' for r in RejectReason),
    'counter_jumps', 'frames_lost', 'other_node_frames',
    'error_frames', 'error_passive_events', 'bus_off_events', 'bus_recoveries',
    'bus_failures', 'bus_reopens', 'tx_errors',
    'commands_received', 'commands_clamped', 'commands_rejected', 'commands_on_bus',
    'commands_superseded', 'commands_lost', 'commands_out_of_order', 'stale_commands',
    'command_frames_sent', 'pressure_frames_sent', 'watchdog_trips', 'foreign_command_frames',
    'fault_clear_requests', 'telemetry_losses', 'internal_errors',
)

#: ValveStatus fault flags that latch: the output stays off until ClearFaults (and the
#: condition is gone). The others are active conditions that clear by themselves (command
#: flags are held 1 s after the event).
LATCHED_FLAGS = ('Overcurrent', 'Overtemperature', 'Internal')


class Tally:
    """Counters and the time of the last event of each kind ("marks").

    Not thread-safe by itself: every component of the driver core changes it only while
    holding the core's one lock, and :meth:`copy` is taken under that lock too.
    """

    def __init__(self) -> None:
        self.counts: dict[str, int] = dict.fromkeys(COUNTER_KEYS, 0)
        self._marks: dict[str, float] = {}

    def count(self, key: str, n: int = 1) -> None:
        """Add ``n`` to counter ``key``."""
        self.counts[key] = self.counts.get(key, 0) + n

    def mark(self, key: str, now: float) -> None:
        """Remember that an event ``key`` happened at monotonic time ``now``."""
        self._marks[key] = now

    def recent(self, now: float, hold_s: float) -> frozenset[str]:
        """The event kinds seen within ``hold_s`` before ``now``."""
        return frozenset(k for k, t in self._marks.items() if now - t <= hold_s)

    def copy(self) -> dict[str, int]:
        """A copy of the counters."""
        return dict(self.counts)


@dataclass(frozen=True, slots=True)
class BusSnapshot:
    """The bus link's state at one instant (see :class:`~.bus_link.BusLink`)."""

    failed: bool
    error_text: str
    condition: BusCondition
    last_error_frame: str

    def problem(self) -> tuple[Level, str] | None:
        """The level and text of a bus problem (failed, bus-off, error passive or warning);
        None while the controller is error active."""
        if self.failed:
            return Level.ERROR, f'bus failed ({self.error_text}); reopening'
        if self.condition is BusCondition.BUS_OFF:
            return Level.ERROR, f'bus-off ({self.last_error_frame})'
        if self.condition is BusCondition.ERROR_PASSIVE:
            return Level.WARN, f'error passive ({self.last_error_frame})'
        if self.condition is BusCondition.WARNING:
            return Level.WARN, f'error warning ({self.last_error_frame})'
        return None


#: The bus counters both drivers report in the ``CAN bus`` status.
BUS_COUNTERS = ('error_frames', 'error_passive_events', 'bus_off_events', 'bus_recoveries',
                'bus_failures', 'bus_reopens', 'tx_errors')


@dataclass(frozen=True)
class CoreSnapshot:
    """What every driver core's diagnostics need, copied at one instant (monotonic
    ``now``): the configuration, the counters and recent event marks, open and active,
    the bus."""

    config: DriverConfig
    now: float
    counters: Mapping[str, int]
    recent: frozenset[str]
    closed: bool
    active: bool
    bus: BusSnapshot


@dataclass(frozen=True)
class DriverSnapshot(CoreSnapshot):
    """Everything the suite's diagnostics need, copied at one instant."""

    # receive tracker
    last_reject: str
    telemetry_age_s: float
    telemetry_lost: bool
    lost_after_s: float
    loss_reason: str
    frozen_run: int
    frozen_counter: int | None
    telemetry_rate_hz: float
    average_source: str
    last_status: Mapping | None
    heartbeat_age_s: float
    # transmit scheduler
    duty: float
    pwm_frequency_hz: float
    watchdog_tripped: bool
    last_command_note: str
    host_id: int = 0
    foreign_host_id: int | None = None
    max_command_age_s: float = 0.0
    last_stale_age_s: float = 0.0
    # drive mode: sent (the drive_mode setting) and in force (the controller's ValveDrive)
    drive_mode: str = 'normal'
    last_drive: Mapping | None = None
    drive_age_s: float = math.inf


def _pick(counters: Mapping[str, int], keys: Iterable[str]) -> dict[str, int]:
    return {k: counters[k] for k in keys}


def _bus_status(s: DriverSnapshot) -> StatusReport:
    recent = s.recent
    problem = s.bus.problem()
    if s.closed:
        status = StatusReport('CAN bus', Level.STALE, 'bus closed')
    elif problem is not None:
        status = StatusReport('CAN bus', *problem)
    elif recent & {'rejected_unknown_id', 'rejected_frame_type', 'tx_error'}:
        status = StatusReport('CAN bus', Level.WARN, 'send errors' if 'tx_error' in recent
                              else f'bus problems: {s.last_reject}')
    else:
        status = StatusReport('CAN bus', Level.OK, 'error active')
    status.values = {
        'hardware': s.config.hardware_id, 'condition': s.bus.condition.value,
        **_pick(s.counters, (*BUS_COUNTERS, 'rejected_unknown_id', 'rejected_frame_type',
                             'other_node_frames')),
        'last_error_frame': s.bus.last_error_frame}
    return status


def _telemetry_status(s: DriverSnapshot) -> StatusReport:
    cfg = s.config
    limit = cfg.telemetry_timeout_s
    frozen = s.frozen_run >= cfg.frozen_counter_limit
    rejected = sorted(k[len('rejected_'):] for k in s.recent
                      if k.startswith('rejected_')
                      and k not in ('rejected_unknown_id', 'rejected_frame_type'))
    if s.closed:
        status = StatusReport('telemetry', Level.STALE, 'bus closed')
    elif s.telemetry_lost:
        detail = f'; recent rejections: {", ".join(rejected)}' if rejected else ''
        if s.loss_reason == 'counter gaps':
            text = (f'telemetry lost: frames missing (counter gaps) in '
                    f'{cfg.telemetry_error_windows} consecutive {cfg.telemetry_window_s:g} s '
                    'windows')
        else:
            why = (f'counter frozen at {s.frozen_counter}' if frozen
                   else 'no valid ValveTelemetry')
            text = (f'telemetry stopped: {why} for {s.telemetry_age_s * 1e3:.1f} ms '
                    f'(limit {limit * 1e3:.2f} ms)')
        status = StatusReport('telemetry', Level.ERROR, text + detail)
    elif frozen:
        status = StatusReport('telemetry', Level.ERROR, f'counter frozen at {s.frozen_counter}')
    elif rejected or 'counter_jump' in s.recent:
        what = rejected + (['counter jumps'] if 'counter_jump' in s.recent else [])
        status = StatusReport('telemetry', Level.WARN,
                              f'frames rejected or lost: {", ".join(what)}; last: '
                              f'{s.last_reject or "counter jump"}')
    else:
        status = StatusReport('telemetry', Level.OK, f'{s.telemetry_rate_hz:.0f} Hz')
    status.values = {
        'age_s': s.telemetry_age_s, 'timeout_s': limit, 'average_source': s.average_source,
        'lost_after_s': s.lost_after_s, 'loss_reason': s.loss_reason,
        'rate_hz': s.telemetry_rate_hz,
        **_pick(s.counters, ('telemetry_frames', 'telemetry_losses', 'rejected_total',
                             'rejected_checksum', 'rejected_wrong_length',
                             'rejected_counter_frozen', 'rejected_out_of_range',
                             'rejected_unknown_id', 'rejected_frame_type', 'counter_jumps',
                             'frames_lost', 'internal_errors')),
        'last_rejection': s.last_reject}
    return status


def _command_status(s: DriverSnapshot) -> StatusReport:
    timeout = s.config.command_timeout_s
    second_host = 'foreign_command' in s.recent
    if s.closed:
        status = StatusReport('commands', Level.STALE, 'bus closed')
    elif second_host:
        status = StatusReport('commands', Level.ERROR,
                              f'another host (host id {s.foreign_host_id}) commands node '
                              f'{s.config.node_id}: two hosts on one valve (this host id '
                              f'{s.host_id})')
    elif s.watchdog_tripped:
        status = StatusReport('commands', Level.WARN,
                              f'watchdog: no duty command for {timeout:g} s; '
                              'valve commanded closed (duty 0)')
    elif s.recent & {'command_rejected', 'command_clamped'}:
        status = StatusReport('commands', Level.WARN, s.last_command_note)
    elif 'stale_command' in s.recent:
        status = StatusReport('commands', Level.WARN,
                              f'stale commands: {s.counters["stale_commands"]} reached the bus '
                              f'later than {s.config.stale_command_s * 1e3:g} ms after their '
                              f'stamp (last {s.last_stale_age_s * 1e3:.1f} ms)')
    elif 'command_lost' in s.recent:
        status = StatusReport('commands', Level.WARN,
                              f'commands lost: {s.counters["commands_lost"]} sequence numbers '
                              'missing')
    elif not s.active:
        status = StatusReport('commands', Level.OK, 'inactive: not sending')
    else:
        status = StatusReport('commands', Level.OK,
                              f'duty {s.duty:.4g} at {s.pwm_frequency_hz:g} Hz')
    status.values = {
        'duty': s.duty, 'pwm_frequency_hz': s.pwm_frequency_hz, 'active': s.active,
        'watchdog_tripped': s.watchdog_tripped, 'command_timeout_s': timeout,
        **_pick(s.counters, ('commands_received', 'commands_clamped', 'commands_rejected',
                             'commands_on_bus', 'commands_superseded', 'commands_lost',
                             'commands_out_of_order', 'stale_commands',
                             'command_frames_sent', 'pressure_frames_sent',
                             'watchdog_trips', 'foreign_command_frames')),
        'stale_command_s': s.config.stale_command_s,
        'max_command_age_s': s.max_command_age_s, 'host_id': s.host_id,
        'foreign_host_id': '' if s.foreign_host_id is None else s.foreign_host_id,
        'last_command_problem': s.last_command_note}
    return status


_STATE_NAMES = {0: 'init', 1: 'standby', 2: 'running', 3: 'fault'}
_DRIVE_MODE_NAMES = {int(m): m.name.lower() for m in DriveMode}


def _controller_status(s: DriverSnapshot) -> StatusReport:
    heartbeat = s.last_status
    age = s.heartbeat_age_s
    flags = fault_flags(heartbeat)
    latched = [f for f in flags if f in LATCHED_FLAGS]
    active = [f for f in flags if f not in LATCHED_FLAGS]
    state = int(heartbeat['ControllerState']) if heartbeat else -1
    state_name = _STATE_NAMES.get(state, 'unknown')
    if s.closed:
        status = StatusReport('controller', Level.STALE, 'bus closed')
    elif heartbeat is None or age > s.config.status_timeout_s:
        status = StatusReport('controller', Level.WARN if heartbeat is None else Level.ERROR,
                              'no ValveStatus heartbeat' + (
                                  '' if heartbeat is None else f' for {age:.2f} s'))
    elif state == 3 or latched:
        parts = ([f'latched: {", ".join(latched)} (clear with ~/clear_faults)'] if latched
                 else [state_name])
        if active:
            parts.append(f'active: {", ".join(active)}')
        status = StatusReport('controller', Level.ERROR, 'controller fault: ' + '; '.join(parts))
    elif active:
        status = StatusReport('controller', Level.WARN,
                              f'controller reports {", ".join(active)} (active)')
    else:
        status = StatusReport('controller', Level.OK, state_name)
    status.values = {'state': state_name, 'fault_flags': ','.join(flags),
                     'latched_faults': ','.join(latched), 'active_faults': ','.join(active),
                     'fault_clear_requests': s.counters['fault_clear_requests'],
                     'heartbeat_age_s': age, 'status_frames': s.counters['status_frames']}
    if heartbeat:
        status.values.update(duty_active=heartbeat['DutyActive'],
                             pwm_frequency_active_hz=heartbeat['PwmFrequencyActive'],
                             supply_voltage_v=heartbeat['SupplyVoltage'])
    status.values['drive_mode_requested'] = s.drive_mode
    drive = s.last_drive
    if drive:   # what the controller reports of its electronics (ValveDrive)
        status.values.update(
            drive_mode=_DRIVE_MODE_NAMES.get(int(drive['DriveModeActive']), 'unknown'),
            holding_current_a=drive['HoldingCurrent'],
            capacitor_voltage_v=drive['CapacitorVoltage'],
            supply_voltage_v=drive['SupplyVoltageMeasured'], drive_age_s=s.drive_age_s,
            drive_frames=s.counters.get('drive_frames', 0))
    return status


def diagnose(snapshot: DriverSnapshot) -> list[StatusReport]:
    """The four statuses of the driver at the snapshot's instant (a pure function).

    Returns
    -------
    list[StatusReport]
        CAN bus, telemetry, commands, controller; each with its counters as values.
    """
    reports = [_bus_status(snapshot), _telemetry_status(snapshot),
               _command_status(snapshot), _controller_status(snapshot)]
    for report in reports:
        report.values.setdefault('hardware', snapshot.config.hardware_id)
    return reports


def overall_level(reports: Iterable[StatusReport]) -> Level:
    """Worst level of ``reports`` (STALE counts as ERROR)."""
    worst = max((r.level for r in reports), default=Level.OK)
    return Level.ERROR if worst is Level.STALE else Level(worst)


def fault_flags(status: Mapping | None) -> list[str]:
    """The fault flags set in a decoded ValveStatus (names without ``Fault``), sorted."""
    return sorted(k[len('Fault'):] for k, v in (status or {}).items()
                  if k.startswith('Fault') and v)


def age(now: float, then: float | None) -> float:
    """``now - then``, or infinity when ``then`` is None [s]."""
    return math.inf if then is None else now - then
