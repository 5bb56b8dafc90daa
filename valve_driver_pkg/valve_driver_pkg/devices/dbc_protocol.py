"""A user's own board with a DBC of its own, for valve_can_driver (protocol ``dbc``).

``dbc.mapping_file`` is a flat YAML of ``role: Message.Signal``; roles: ``duty``
(required), ``pwm_frequency``, ``enable``, ``counter``, ``checksum`` (host -> board, in the
command messages), ``current``, ``position`` (board -> host). A role naming a message or
signal that is not in the DBC is refused at configure with its name.

Scaling is the DBC's (factor, offset, range); units come from the signal's unit:

* duty: ``%`` (0..100), per mille (``‰``, ``per mille``, ``permille``, ``promille``;
  0..1000), none (0..1); anything else is refused;
* current: ``A`` or ``mA`` (none: A); position: ``m``, ``mm``, ``um``/``µm`` (none: m);
  PWM frequency: ``Hz``, ``kHz`` (none: Hz).

A command message goes out every ``GenMsgCycleTime`` (else ``command_rate_hz``) and at
once on a change; the board's messages' ``GenMsgCycleTime`` (else 100 ms) is its liveness
period. Motorola and Intel byte order, extended ids and multiplexed messages come from
cantools: a mapped signal in a multiplexed message is sent with its multiplexer value,
and read from the frames that carry it. The ``counter`` role is +1 per frame (wrapping at
the signal's maximum); ``checksum`` is CRC-8/SAE-J1850 over the frame's other data bytes
(the signal must be a whole byte). Every other signal of a command message is sent at its
``initial`` value from the DBC (else 0, or the range's minimum when 0 is outside).
"""
from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
import yaml
from crccheck.crc import Crc8SaeJ1850

from valve_driver_pkg.devices.base import DeviceProtocol, DeviceReading, FrameOutcome
from valve_driver_pkg.errors import MappingError

__all__ = ['DbcProtocol', 'RoleSignal', 'load_dbc_mapping', 'DUTY_UNITS', 'COMMAND_ROLES',
           'DEVICE_ROLES', 'example_dbc_path', 'example_mapping_path']

COMMAND_ROLES = ('duty', 'pwm_frequency', 'enable', 'counter', 'checksum')
DEVICE_ROLES = ('current', 'position')
#: Signal unit -> device units per unit of the role's SI quantity.
DUTY_UNITS = {'%': 100.0, '‰': 1000.0, 'per mille': 1000.0, 'permille': 1000.0,
              'promille': 1000.0, '': 1.0}
_CURRENT_UNITS = {'a': 1.0, 'ma': 1e3, '': 1.0}
_POSITION_UNITS = {'m': 1.0, 'mm': 1e3, 'um': 1e6, 'µm': 1e6, '': 1.0}
_FREQUENCY_UNITS = {'hz': 1.0, 'khz': 1e-3, '': 1.0}
_DEFAULT_LIVENESS_S = 0.1
_EXAMPLES = Path(__file__).resolve().parent / 'data' / 'examples'


def example_dbc_path() -> Path:
    """The example board's DBC (Motorola, percent, extended id, multiplexed, no checksum)."""
    return _EXAMPLES / 'board.dbc'


def example_mapping_path() -> Path:
    """The example board's mapping file."""
    return _EXAMPLES / 'board_mapping.yaml'


@dataclass(frozen=True)
class RoleSignal:
    """A role resolved in the DBC: message, signal, units per SI unit, mux value."""

    role: str
    message: object          # cantools Message
    signal: object           # cantools Signal
    per_si: float
    mux: int | None

    @property
    def name(self) -> str:
        return f'{self.message.name}.{self.signal.name}'


def _unit_factor(path: str, role: str, sig, units: Mapping[str, float], what: str) -> float:
    unit = (sig.unit or '').strip()
    key = unit if role == 'duty' else unit.lower()
    if key not in units:
        raise MappingError(f'{path}: role {role!r}: signal {sig.name!r} has unit {unit!r}; '
                           f'{what} must be in {", ".join(repr(u) for u in units if u)} or '
                           'have no unit')
    return units[key]


def _resolve(path: str, dbc_path: str, db, role: str, text: object) -> RoleSignal:
    if not isinstance(text, str) or text.count('.') != 1:
        raise MappingError(f'{path}: role {role!r}: {text!r} is not Message.Signal')
    msg_name, sig_name = text.split('.')
    try:
        message = db.get_message_by_name(msg_name)
    except KeyError:
        raise MappingError(f'{path}: role {role!r}: message {msg_name!r} is not in the DBC '
                           f'{dbc_path}') from None
    try:
        sig = message.get_signal_by_name(sig_name)
    except KeyError:
        raise MappingError(f'{path}: role {role!r}: signal {sig_name!r} is not in message '
                           f'{msg_name!r} of the DBC {dbc_path}') from None
    factor = 1.0
    if role == 'duty':
        factor = _unit_factor(path, role, sig, DUTY_UNITS, 'a duty')
    elif role == 'current':
        factor = _unit_factor(path, role, sig, _CURRENT_UNITS, 'a current')
    elif role == 'position':
        factor = _unit_factor(path, role, sig, _POSITION_UNITS, 'a position')
    elif role == 'pwm_frequency':
        factor = _unit_factor(path, role, sig, _FREQUENCY_UNITS, 'a frequency')
    elif role == 'checksum' and (sig.length != 8 or sig.start % 8 != (
            7 if sig.byte_order == 'big_endian' else 0)):
        raise MappingError(f'{path}: role checksum: signal {sig_name!r} must be one whole '
                           'byte')
    mux = sig.multiplexer_ids[0] if sig.multiplexer_ids else None
    return RoleSignal(role, message, sig, factor, mux)


def load_dbc_mapping(dbc_file: str, mapping_file: str) -> dict[str, RoleSignal]:
    """Resolve every role of ``mapping_file`` in ``dbc_file``.

    Raises
    ------
    MappingError
        A file that cannot be read, an unknown role, a role naming a message or signal
        not in the DBC (named), a unit the role cannot take, a command role in the
        board's message or the other way round.
    """
    if not dbc_file or not mapping_file:
        raise MappingError('protocol dbc needs dbc.file and dbc.mapping_file')
    try:
        db = cantools.database.load_file(dbc_file)
    except (OSError, cantools.database.UnsupportedDatabaseFormatError, ValueError) as err:
        raise MappingError(f'{dbc_file}: cannot read the DBC: '
                           f'{str(err).splitlines()[0] if str(err) else err}') from err
    try:
        data = yaml.safe_load(Path(mapping_file).read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise MappingError(f'{mapping_file}: cannot read the mapping: '
                           f'{str(err).splitlines()[0]}') from err
    if not isinstance(data, dict) or 'duty' not in data:
        raise MappingError(f'{mapping_file}: a flat YAML of role: Message.Signal with at '
                           'least duty')
    unknown = set(data) - set(COMMAND_ROLES) - set(DEVICE_ROLES)
    if unknown:
        raise MappingError(f'{mapping_file}: unknown role(s) '
                           f'{", ".join(sorted(map(str, unknown)))}; roles: '
                           f'{", ".join(COMMAND_ROLES + DEVICE_ROLES)}')
    roles = {role: _resolve(mapping_file, dbc_file, db, role, text)
             for role, text in data.items()}
    command_messages = {r.message.name for n, r in roles.items() if n in COMMAND_ROLES}
    for name in DEVICE_ROLES:
        if name in roles and roles[name].message.name in command_messages:
            raise MappingError(f'{mapping_file}: role {name!r}: {roles[name].name} is in a '
                               'message the host sends')
    return roles


def _initial(sig) -> float:
    value = sig.initial if sig.initial is not None else 0
    lo = sig.minimum if sig.minimum is not None else -math.inf
    hi = sig.maximum if sig.maximum is not None else math.inf
    return value if lo <= value <= hi else lo


class DbcProtocol(DeviceProtocol):
    """The user's board (see the module docstring).

    Parameters
    ----------
    roles : dict[str, RoleSignal]
        From :func:`load_dbc_mapping`.
    command_period_s : float
        Used for a command message without ``GenMsgCycleTime`` [s].
    label : str
        The device in diagnostics names.
    """

    name = 'dbc'

    def __init__(self, roles: dict[str, RoleSignal], command_period_s: float,
                 label: str = 'dbc board') -> None:
        self.roles = roles
        self.sends_pwm_frequency = 'pwm_frequency' in roles
        self.measures_position = 'position' in roles
        duty_msg = roles['duty'].message
        period = (duty_msg.cycle_time / 1000.0 if duty_msg.cycle_time else command_period_s)
        device = [r.message for n, r in roles.items() if n in DEVICE_ROLES]
        if device:
            times = [m.cycle_time for m in device if m.cycle_time]
            liveness = min(times) / 1000.0 if times else _DEFAULT_LIVENESS_S
        else:
            liveness = math.inf
        super().__init__(label, period, liveness)
        self._commands: dict[str, object] = {}
        for name in COMMAND_ROLES:
            if name in roles:
                self._commands.setdefault(roles[name].message.name, roles[name].message)
        self._device_ids = {(m.frame_id, m.is_extended_frame) for m in device}
        self._counter = 0
        self._lock = threading.Lock()
        self._latest: dict[str, float] = {}
        self.pwm_frequency_hz = 50.0
        self.rejected = 0

    @classmethod
    def from_files(cls, dbc_file: str, mapping_file: str,
                   command_period_s: float) -> DbcProtocol:
        """Resolve the mapping in the DBC and build the protocol (MappingError if not)."""
        roles = load_dbc_mapping(dbc_file, mapping_file)
        return cls(roles, command_period_s, f'dbc {Path(dbc_file).stem}')

    def set_frequency(self, pwm_frequency_hz: float) -> None:
        self.pwm_frequency_hz = pwm_frequency_hz

    def command_frames(self, duty: float, enable: bool) -> list[can.Message]:
        self._counter += 1
        return [self._encode(message, duty if enable else 0.0, enable)
                for message in self._commands.values()]

    def _encode(self, message, duty: float, enable: bool) -> can.Message:
        values = {'duty': duty, 'enable': 1.0 if enable else 0.0,
                  'pwm_frequency': self.pwm_frequency_hz}
        mine = {r.signal.name: r for r in self.roles.values() if r.message is message}
        mux_values = {r.mux for r in mine.values() if r.mux is not None}
        mux = mux_values.pop() if mux_values else None
        signals = {}
        for sig in message.signals:
            if sig.multiplexer_ids and mux not in sig.multiplexer_ids:
                continue
            if sig.is_multiplexer:
                signals[sig.name] = mux if mux is not None else _initial(sig)
                continue
            role = mine.get(sig.name)
            value = _initial(sig)
            if role is not None and role.role in values:
                value = values[role.role] * role.per_si
            elif role is not None and role.role == 'counter':
                top = int(sig.maximum) if sig.maximum is not None else (1 << sig.length) - 1
                value = self._counter % (top + 1)
            elif role is not None and role.role == 'checksum':
                value = 0
            lo = sig.minimum if sig.minimum is not None else -math.inf
            hi = sig.maximum if sig.maximum is not None else math.inf
            signals[sig.name] = min(max(value, lo), hi)
        data = bytearray(message.encode(signals, scaling=True, strict=True))
        checksum = next((r for r in mine.values() if r.role == 'checksum'), None)
        if checksum is not None:
            byte = (checksum.signal.start // 8)
            rest = bytes(data[:byte] + data[byte + 1:])
            data[byte] = Crc8SaeJ1850.calc(rest)
        return can.Message(arbitration_id=message.frame_id,
                           is_extended_id=message.is_extended_frame, data=bytes(data))

    def decode_command(self, msg: can.Message) -> float | None:
        duty = self.roles['duty']
        if msg.arbitration_id != duty.message.frame_id or \
                msg.is_extended_id != duty.message.is_extended_frame:
            return None
        try:
            decoded = duty.message.decode(bytes(msg.data), decode_choices=False)
        except Exception:   # noqa: BLE001 - cantools raises several kinds on bad data
            return None
        if duty.signal.name not in decoded:
            return None
        value = float(decoded[duty.signal.name]) / duty.per_si
        enable = self.roles.get('enable')
        if enable is not None and enable.message is duty.message and \
                not decoded.get(enable.signal.name, 1):
            return 0.0
        return value

    def on_frame(self, msg: can.Message) -> FrameOutcome:
        if msg.is_error_frame or msg.is_remote_frame:
            return FrameOutcome()
        if (msg.arbitration_id, msg.is_extended_id) not in self._device_ids:
            return FrameOutcome()
        found = {}
        for name in DEVICE_ROLES:
            role = self.roles.get(name)
            if role is None or role.message.frame_id != msg.arbitration_id:
                continue
            try:
                decoded = role.message.decode(bytes(msg.data), decode_choices=False)
            except Exception:   # noqa: BLE001 - cantools raises several kinds on bad data
                with self._lock:
                    self.rejected += 1
                return FrameOutcome(from_device=True)
            if role.signal.name in decoded:
                found[name] = float(decoded[role.signal.name]) / role.per_si
        if not found:
            return FrameOutcome(from_device=True)
        with self._lock:
            self._latest.update(found)
            latest = dict(self._latest)
        primary = 'current' if 'current' in self.roles else 'position'
        if primary not in found:
            return FrameOutcome(from_device=True)
        return FrameOutcome(from_device=True, reading=DeviceReading(
            coil_current_a=latest.get('current', math.nan),
            spool_position_m=latest.get('position', math.nan)))

    def describe(self) -> dict:
        return {role: r.name for role, r in self.roles.items()}
