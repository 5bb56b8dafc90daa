"""Diagnostics of a device protocol: a snapshot in, four statuses out (a pure function).

Statuses: ``CAN bus`` (condition, failures, restarts, the host's own bus problems such as
a lost J1939 address claim), ``device`` (set-up, liveness), ``commands`` (watchdog,
clamped or rejected commands), ``faults`` (what the device reports: CANopen EMCY, J1939
DM1; a refused SDO access). Every one is OK when all is well: "recovered" means all four
OK again.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from valve_driver_pkg.devices.base import LIVENESS_PERIODS, DeviceFault
from valve_driver_pkg.driver.diagnostics import BUS_COUNTERS, CoreSnapshot, Level, StatusReport

__all__ = ['DeviceSnapshot', 'diagnose_device', 'STATUS_NAMES']

#: The statuses of a device driver, in order.
STATUS_NAMES = ('CAN bus', 'device', 'commands', 'faults')


@dataclass(frozen=True)
class DeviceSnapshot(CoreSnapshot):
    """Everything the device diagnostics need, copied at one instant."""

    label: str
    bus_problem: str
    setup_state: str
    setup_ok: bool
    device_lost: bool
    lost_after_s: float
    device_age_s: float
    liveness_limit_s: float
    next_restart_in_s: float
    restarts_in_row: int
    restart_backoff_s: float
    faults: tuple[DeviceFault, ...]
    device_values: Mapping
    duty: float
    pwm_frequency_hz: float
    watchdog_tripped: bool
    last_command_note: str


def _count(s: DeviceSnapshot, *keys: str) -> dict:
    return {k: s.counters.get(k, 0) for k in keys}


def _bus(s: DeviceSnapshot) -> StatusReport:
    problem = s.bus.problem()
    if s.closed:
        level, text = Level.STALE, 'bus closed'
    elif problem is not None and problem[0] is Level.ERROR:
        level, text = Level.ERROR, (f'{problem[1]}; next restart in '
                                    f'{s.next_restart_in_s:.2f} s (bounded back-off)')
    elif s.bus_problem:
        level, text = Level.ERROR, s.bus_problem
    elif problem is not None:
        level, text = problem
    else:
        level, text = Level.OK, 'error active'
    return StatusReport('CAN bus', level, text, {
        'condition': s.bus.condition.value, 'last_error_frame': s.bus.last_error_frame,
        'next_restart_in_s': s.next_restart_in_s, 'restarts_in_row': s.restarts_in_row,
        'restart_backoff_s': s.restart_backoff_s,
        **_count(s, *BUS_COUNTERS, 'bus_restarts', 'frames_sent')})


def _device(s: DeviceSnapshot) -> StatusReport:
    limit_s = s.liveness_limit_s
    if s.closed:
        level, text = Level.STALE, 'bus closed'
    elif not s.setup_ok and s.setup_state.startswith('set-up failed'):
        level, text = Level.ERROR, f'{s.label}: {s.setup_state}'
    elif s.device_lost:
        level, text = Level.ERROR, (f'{s.label} silent for {s.device_age_s * 1e3:.0f} ms '
                                    f'(limit {LIVENESS_PERIODS} periods = '
                                    f'{limit_s * 1e3:.0f} ms); valve/state stopped')
    elif not s.setup_ok:
        level, text = Level.WARN, f'{s.label}: {s.setup_state}'
    elif 'stale_frame' in s.recent:
        level, text = Level.WARN, (f'{s.label}: frames older than {limit_s * 1e3:.0f} ms '
                                   'when handled were dropped (the host falls behind the bus)')
    else:
        level, text = Level.OK, f'{s.label}: set up, answering'
    values = {'setup': s.setup_state, 'lost': s.device_lost, 'lost_after_s': s.lost_after_s,
              'age_s': s.device_age_s, 'liveness_limit_s': limit_s,
              **_count(s, 'device_frames', 'stale_frames', 'device_losses', 'setups',
                       'setup_failures')}
    values.update(s.device_values)
    return StatusReport('device', level, text, values)


def _commands(s: DeviceSnapshot) -> StatusReport:
    timeout = s.config.command_timeout_s
    if s.closed:
        level, text = Level.STALE, 'bus closed'
    elif s.watchdog_tripped:
        level, text = Level.WARN, (f'watchdog: no duty command for {timeout:g} s; valve '
                                   'commanded closed (duty 0)')
    elif s.recent & {'command_rejected', 'command_clamped'}:
        level, text = Level.WARN, s.last_command_note
    elif not s.active:
        level, text = Level.OK, 'inactive: not sending'
    else:
        level, text = Level.OK, f'duty {s.duty:.4g}'
    return StatusReport('commands', level, text, {
        'duty': s.duty, 'pwm_frequency_hz': s.pwm_frequency_hz, 'active': s.active,
        'watchdog_tripped': s.watchdog_tripped, 'command_timeout_s': timeout,
        **_count(s, 'commands_received', 'commands_clamped', 'commands_rejected',
                 'commands_lost', 'command_frames_sent', 'watchdog_trips'),
        'last_command_problem': s.last_command_note})


def _faults(s: DeviceSnapshot) -> StatusReport:
    if s.closed:
        return StatusReport('faults', Level.STALE, 'bus closed')
    errors = [f for f in s.faults if f.error]
    warnings = [f for f in s.faults if not f.error]
    values: dict = {'active_faults': '; '.join(f.text for f in s.faults)}
    for fault in s.faults:
        values.update(fault.values)
    if errors:
        return StatusReport('faults', Level.ERROR, '; '.join(f.text for f in errors), values)
    if warnings:
        return StatusReport('faults', Level.WARN, '; '.join(f.text for f in warnings), values)
    return StatusReport('faults', Level.OK, 'none reported', values)


def diagnose_device(snapshot: DeviceSnapshot) -> list[StatusReport]:
    """The four statuses (``STATUS_NAMES``) at the snapshot's instant."""
    reports = [_bus(snapshot), _device(snapshot), _commands(snapshot), _faults(snapshot)]
    hardware = f'{snapshot.config.interface}:{snapshot.config.channel} {snapshot.label}'
    for report in reports:
        report.values.setdefault('hardware', hardware)
    return reports
