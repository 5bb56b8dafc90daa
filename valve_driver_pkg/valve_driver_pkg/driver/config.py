"""The driver's settings and their defaults, written once.

:class:`DriverConfig` is read by the driver core and by ``valve_can_driver``: the node
declares one ROS parameter per field, with the field's default, the description and the
range stored in the field's metadata (:func:`setting`). A default changed here changes
both; nothing else spells it.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from valve_driver_pkg.protocol.codec import MAX_NODE_ID
from valve_model_pkg.model.constants import ATMOSPHERIC_PRESSURE_PA

__all__ = ['DriverConfig', 'setting']


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
    telemetry_timeout_periods: float = setting(2.5, 'Telemetry is lost (ERROR) this many '
                                               'telemetry periods after the last valid '
                                               'frame', 1.0, 1000.0)
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
                                      '[Hz]', 0.1, 1000.0)
    max_pwm_frequency_hz: float = setting(1000.0, 'Commands above this PWM frequency are '
                                          'clamped [Hz] (to the DBC limit if lower)',
                                          0.1, 1000.0)
    supply_pressure_pa: float = setting(400_000.0, 'Supply pressure, gauge [Pa], until '
                                        'valve/supply_pressure is received', 0.0, 1.0e6)
    output_pressure_pa: float = setting(0.0, 'Output port pressure, gauge [Pa], until '
                                        'valve/output_pressure is received',
                                        -ATMOSPHERIC_PRESSURE_PA, 1.0e6)

    @property
    def telemetry_period_s(self) -> float:
        """Expected ``ValveTelemetry`` period [s]."""
        return 1.0 / self.telemetry_rate_hz

    @property
    def telemetry_timeout_s(self) -> float:
        """Telemetry is declared lost this long after the last valid frame [s]."""
        return self.telemetry_timeout_periods * self.telemetry_period_s

    @property
    def hardware_id(self) -> str:
        """``interface:channel node n``, the hardware id of the diagnostics."""
        return f'{self.interface}:{self.channel} node {self.node_id}'
