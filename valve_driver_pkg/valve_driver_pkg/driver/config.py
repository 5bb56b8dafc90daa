"""The driver's settings and their defaults, written once.

:class:`DriverConfig` is read by the driver core and by ``valve_can_driver``: the node
declares one ROS parameter per field, with the field's default, the description and the
range stored in the field's metadata (:func:`setting`). A default changed here changes
both; nothing else spells it.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from valve_driver_pkg.protocol.codec import MAX_NODE_ID, DriveMode
from valve_model_pkg.interface import MAX_PWM_FREQUENCY_HZ, MIN_PWM_FREQUENCY_HZ
from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA

__all__ = ['DriverConfig', 'setting', 'DRIVE_MODE_NAMES', 'PROTOCOLS', 'check_protocol_settings']

#: Values of the ``protocol`` setting: the suite's own protocol and the devices' protocols.
PROTOCOLS = ('suite', 'canopen', 'j1939', 'dbc')

#: Values of the ``drive_mode`` setting (``ValveCommand.DriveMode``, lower case).
DRIVE_MODE_NAMES = tuple(mode.name.lower() for mode in DriveMode)


def setting(default, description: str, low: float | None = None,
            high: float | None = None):
    """A dataclass field with the description and range of its ROS parameter.

    Parameters
    ----------
    default : float | int | str
        The default (also the parameter's default).
    description : str
        What ``ros2 param describe`` shows; units in brackets.
    low, high : float | int | None
        Inclusive range of a numeric parameter.
    """
    return dataclasses.field(default=default, metadata={
        'description': description, 'range': None if low is None else (low, high)})


@dataclass(frozen=True)
class DriverConfig:
    """Settings of the driver core (the node fills it from its parameters).

    Each field's metadata holds its description and range (see :func:`setting`); the
    descriptions are the documentation of the fields.
    """

    protocol: str = setting('suite', 'What the device on the bus speaks: suite (the suite\'s '
                            'own DBC, valve_controller_emulator), canopen (CiA 401 I/O '
                            'module), j1939 (ISO 11783-7 auxiliary valve), dbc (the user\'s '
                            'own DBC); see docs/controllers.md')
    interface: str = setting('socketcan', 'python-can interface (socketcan, virtual, pcan, '
                             '...) or tcp_loopback (the emulator\'s loopback hub)')
    channel: str = setting('can0', 'Channel: can0, a virtual channel name, or '
                           '127.0.0.1:PORT')
    bitrate: int = setting(500_000, 'CAN bit rate [bit/s] (socketcan: set with ip link '
                           'instead)', 10_000, 1_000_000)
    node_id: int = setting(0, 'Controller node id: frame id = DBC id + node id', 0,
                           MAX_NODE_ID)
    dbc_path: str = setting('', 'DBC file of the protocol; empty = the one shipped with the '
                            'package')
    command_rate_hz: float = setting(100.0, 'ValveCommand refresh rate [Hz] (also sent on '
                                     'every command)', 1.0, 1000.0)
    command_timeout_s: float = setting(0.5, 'Watchdog: no duty command for this long '
                                       'commands duty 0 [s]; 0 = off', 0.0, 60.0)
    telemetry_rate_hz: float = setting(1000.0, 'Expected ValveTelemetry rate of the '
                                       'controller [Hz]', 1.0, 10000.0)
    telemetry_timeout_periods: float = setting(50.0, 'Telemetry silence longer than this many '
                                               'telemetry periods (or telemetry_timeout_min_s, '
                                               'whichever is longer) is an ERROR', 1.0, 1.0e6)
    telemetry_timeout_min_s: float = setting(0.1, 'Shortest telemetry silence that is an ERROR '
                                             '[s]', 0.001, 60.0)
    telemetry_window_s: float = setting(0.1, 'Telemetry loss is judged over windows of this '
                                        'length [s]', 0.01, 10.0)
    telemetry_loss_fraction: float = setting(0.5, 'A window is bad when at least this fraction '
                                             'of its frames is missing (counter gaps)',
                                             0.01, 1.0)
    telemetry_error_windows: int = setting(3, 'Consecutive bad windows that make the '
                                           'telemetry ERROR', 1, 100)
    telemetry_ok_windows: int = setting(3, 'Consecutive good windows that end a telemetry '
                                        'ERROR', 1, 100)
    status_timeout_s: float = setting(0.35, 'ValveStatus heartbeat missing this long is an '
                                      'ERROR [s]', 0.01, 60.0)
    pressure_rate_hz: float = setting(10.0, 'ValvePressure refresh rate [Hz]', 0.1, 1000.0)
    fault_hold_s: float = setting(1.0, 'A rejected frame or clamped command keeps its WARN '
                                  'this long [s]', 0.0, 3600.0)
    reopen_period_s: float = setting(0.5, 'Pause between attempts to reopen a failed bus '
                                     '[s]', 0.01, 60.0)
    open_timeout_s: float = setting(5.0, 'How long configure waits for the bus '
                                    '(tcp_loopback: the hub) [s]', 0.0, 120.0)
    frozen_counter_limit: int = setting(3, 'Repeated ValveTelemetry counters in a row that '
                                        'make the counter "frozen" (ERROR)', 1, 100)
    pwm_frequency_hz: float = setting(50.0, 'PWM frequency in force until a command sets one '
                                      '[Hz]; for a protocol that carries none (canopen, '
                                      'j1939) the device\'s own PWM frequency, for the '
                                      'derived position and flow', MIN_PWM_FREQUENCY_HZ,
                                      MAX_PWM_FREQUENCY_HZ)
    max_pwm_frequency_hz: float = setting(MAX_PWM_FREQUENCY_HZ, 'Commands above this PWM '
                                          'frequency are clamped [Hz] (to the DBC limit if '
                                          'lower)', MIN_PWM_FREQUENCY_HZ, MAX_PWM_FREQUENCY_HZ)
    host_id: int = setting(-1, 'Host id sent in every ValveCommand (0..15); -1 = derived from '
                           'the process id', -1, 15)
    stale_command_s: float = setting(0.02, 'A duty command older than this when its frame goes '
                                     'on the bus (from its header stamp, else from receipt) is '
                                     'counted as stale [s]', 0.001, 10.0)
    io_nice: int = setting(-10, 'Nice value of the driver\'s bus I/O threads (Linux, needs '
                           'CAP_SYS_NICE to go below 0); 0 = leave as is', -20, 19)
    io_realtime_priority: int = setting(0, 'SCHED_FIFO priority of the bus I/O threads '
                                        '(Linux, needs CAP_SYS_NICE); 0 = off (then io_nice '
                                        'applies)', 0, 99)
    supply_pressure_pa: float = setting(400_000.0, 'Supply pressure, gauge [Pa], until '
                                        'valve/supply_pressure is received', 0.0, 1.0e6)
    output_pressure_pa: float = setting(0.0, 'Output port pressure, gauge [Pa], until '
                                        'valve/output_pressure is received',
                                        -ATMOSPHERIC_PRESSURE_PA, 1.0e6)
    drive_mode: str = setting('normal', 'Drive mode sent in every ValveCommand: normal (the '
                              'valve\'s electronics: boost, holding-current chopper, capacitor '
                              'release pulse) or bench (all three bypassed: the coil sees the '
                              'supply while duty = 1; bare-coil steps for identification). '
                              'Settable at run time; the controller switches at its next PWM '
                              'period start, at once while duty 0 is in force. Duty 0 and '
                              'every stop act at once in either mode. Protocol suite only '
                              '(the device protocols carry no drive mode: normal)')

    log_frames_file: str = setting('', 'Write every frame received and sent to this candump '
                                   '.log file (python-can\'s logger); empty = off. '
                                   'valve_can_replay turns it into a bag')

    def __post_init__(self) -> None:
        check_protocol_settings(self.protocol, self.drive_mode)

    @property
    def telemetry_period_s(self) -> float:
        """Expected ``ValveTelemetry`` period [s]."""
        return 1.0 / self.telemetry_rate_hz

    @property
    def telemetry_timeout_s(self) -> float:
        """Telemetry silence longer than this is an ERROR [s]: periods or minimum, the longer."""
        return max(self.telemetry_timeout_periods * self.telemetry_period_s,
                   self.telemetry_timeout_min_s)

    @property
    def effective_host_id(self) -> int:
        """The host id sent in ``ValveCommand``: ``host_id``, or the process id mod 16."""
        return self.host_id if self.host_id >= 0 else os.getpid() & 0xF

    @property
    def hardware_id(self) -> str:
        """``interface:channel node n``, the hardware id of the diagnostics."""
        return f'{self.interface}:{self.channel} node {self.node_id}'


def check_protocol_settings(protocol: str, drive_mode: str) -> None:
    """Refuse a protocol that is not one, a drive mode that is not one, and a drive mode
    other than ``normal`` with a device protocol (only the suite's protocol carries one).

    Raises
    ------
    ValueError
        Naming the value and the choices.
    """
    DriveMode.parse(drive_mode)
    if protocol not in PROTOCOLS:
        raise ValueError(f'protocol {protocol!r} is not one of {", ".join(PROTOCOLS)}')
    if protocol != 'suite' and drive_mode != 'normal':
        raise ValueError(f'drive_mode {drive_mode!r} needs protocol suite: protocol '
                         f'{protocol} carries no drive mode (the device\'s own configuration '
                         'sets its electronics); use normal')
