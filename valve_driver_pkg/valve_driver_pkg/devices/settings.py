"""Settings of the device protocols and the factory that builds a protocol from them.

Each dataclass is one parameter namespace of ``valve_can_driver`` (``canopen.node_id``,
``j1939.source_address``, ``dbc.file``, ...): the node declares ``PREFIX.FIELD`` for every
field at start, whatever the protocol, with the field's default, description and range
(:func:`~valve_driver_pkg.driver.config.setting`). Integers are integers.
"""
from __future__ import annotations

from dataclasses import dataclass

from valve_driver_pkg.devices.base import DeviceProtocol
from valve_driver_pkg.driver.config import DriverConfig, setting

__all__ = ['CanopenSettings', 'J1939Settings', 'DbcSettings', 'PROTOCOL_SETTINGS',
           'build_protocol']

#: A NAME (J1939-81) for the host: arbitrary address capable 0, industry group 2
#: (agricultural), vehicle system 0, function 128 (the first non-specific function),
#: manufacturer code 0 (reserved for experiments), identity number 1.
DEFAULT_J1939_NAME = (2 << 60) | (128 << 40) | 1


@dataclass(frozen=True)
class CanopenSettings:
    """``canopen.*``: a CiA 401 I/O module (see docs/controllers.md)."""

    node_id: int = setting(1, 'CANopen node id of the device', 1, 127)
    host_node_id: int = setting(127, 'CANopen node id of the host (its heartbeat producer)',
                                1, 127)
    eds_file: str = setting('', 'EDS of the device; empty = the generic CiA 401 EDS shipped '
                            'with valve_driver_pkg')
    mapping_file: str = setting('', 'YAML: which object carries duty, enable, current, '
                                'position; empty = CiA 401 default (duty -> 0x6411 sub 1 '
                                'per mille in RPDO1, current <- 0x6401 sub 1 mA in TPDO1)')
    heartbeat_ms: int = setting(100, 'Host heartbeat period [ms]; the device\'s heartbeat '
                                'consumer (0x1016) is set to 3 periods, its producer (0x1017) '
                                'to one', 10, 10_000)
    sdo_timeout_s: float = setting(0.3, 'Timeout of one SDO answer [s]', 0.01, 10.0)


@dataclass(frozen=True)
class J1939Settings:
    """``j1939.*``: an ISO 11783-7 / J1939 auxiliary valve."""

    source_address: int = setting(128, 'Source address the host claims (J1939-81)', 0, 253)
    name: int = setting(DEFAULT_J1939_NAME, 'The host\'s 64-bit NAME (J1939-81) as an '
                        'integer; a negative value is the two\'s complement (bit 63 set)',
                        -(2 ** 63), 2 ** 63 - 1)
    valve_index: int = setting(0, 'Auxiliary valve number n: command PGN 65072 + n, '
                               'Estimated Flow PGN 65040 + n', 0, 15)
    command_period_ms: int = setting(100, 'Auxiliary Valve Command period [ms]', 10, 1000)


@dataclass(frozen=True)
class DbcSettings:
    """``dbc.*``: the user's own board and DBC."""

    file: str = setting('', 'The user\'s DBC file')
    mapping_file: str = setting('', 'YAML: role -> Message.Signal (duty required; '
                                'pwm_frequency, enable, current, position, counter, checksum '
                                'optional)')


#: Parameter namespace -> settings class.
PROTOCOL_SETTINGS = {'canopen': CanopenSettings, 'j1939': J1939Settings, 'dbc': DbcSettings}


def build_protocol(config: DriverConfig, canopen: CanopenSettings, j1939: J1939Settings,
                   dbc: DbcSettings) -> DeviceProtocol:
    """The protocol ``config.protocol`` names, from its settings.

    Raises
    ------
    MappingError
        A mapping or EDS/DBC the protocol cannot use (named).
    ValueError
        ``config.protocol`` is ``suite`` (the suite's own core drives it).
    """
    command_period_s = 1.0 / config.command_rate_hz
    if config.protocol == 'canopen':
        from valve_driver_pkg.devices.canopen_mapping import (default_eds_path,
                                                              load_canopen_mapping)
        from valve_driver_pkg.devices.canopen_protocol import CanopenProtocol
        return CanopenProtocol(canopen.node_id, canopen.host_node_id,
                               canopen.eds_file or str(default_eds_path()),
                               load_canopen_mapping(canopen.mapping_file or None),
                               canopen.heartbeat_ms, canopen.sdo_timeout_s, command_period_s)
    if config.protocol == 'j1939':
        from valve_driver_pkg.devices.j1939_protocol import J1939Protocol
        return J1939Protocol(j1939.source_address, j1939.name % (1 << 64), j1939.valve_index,
                             j1939.command_period_ms / 1000.0)
    if config.protocol == 'dbc':
        from valve_driver_pkg.devices.dbc_protocol import DbcProtocol
        return DbcProtocol.from_files(dbc.file, dbc.mapping_file, command_period_s)
    raise ValueError(f'protocol {config.protocol!r} has no device protocol')
