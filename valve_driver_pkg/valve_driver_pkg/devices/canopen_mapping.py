"""The CANopen mapping file: which object carries the duty, the enable, the current.

A YAML of roles (``duty`` required; ``enable``, ``current``, ``position`` optional), each
``{object, subindex, type, scale, pdo}``; ``enable`` has ``on`` (the value written while
enabled, 0 when disabled) instead of ``scale``; an optional ``fail_safe`` list of
``{object, subindex, type, value}`` says what the device's output does on a communication
error when the duty object is neither CiA 401's analog output (0x6411: error mode 0x6443,
error value 0x6444) nor its digital output (0x6200: 0x6206/0x6207). See
``devices/data/cia401_mapping.yaml`` (the CiA 401 default) and docs/controllers.md.

Every object is checked against the EDS (exists, type, PDO-mappable) when the driver is
configured; a missing one is refused naming the file, the role and the object.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import yaml

from valve_driver_pkg.errors import MappingError

__all__ = ['TYPES', 'ObjectRef', 'FailSafeWrite', 'CanopenMapping', 'load_canopen_mapping',
           'default_mapping_path', 'default_eds_path', 'pdo_entry', 'fail_safe_writes']

_DATA = Path(__file__).resolve().parent / 'data'

#: CiA 301 basic data types: name -> (struct format, data type code).
TYPES = {
    'INTEGER8': ('<b', 0x0002), 'INTEGER16': ('<h', 0x0003), 'INTEGER32': ('<i', 0x0004),
    'UNSIGNED8': ('<B', 0x0005), 'UNSIGNED16': ('<H', 0x0006), 'UNSIGNED32': ('<I', 0x0007),
}
_ROLES = ('duty', 'enable', 'current', 'position')


def default_mapping_path() -> Path:
    """The CiA 401 default mapping shipped with the package."""
    return _DATA / 'cia401_mapping.yaml'


def default_eds_path() -> Path:
    """The generic CiA 401 EDS shipped with the package."""
    return _DATA / 'cia401_valve.eds'


@dataclass(frozen=True, slots=True)
class ObjectRef:
    """One mapped object: where it is, its type, its scale and its PDO number."""

    role: str
    index: int
    subindex: int
    type: str
    scale: float = 1.0
    pdo: int = 1
    on_value: int = 1

    @property
    def bits(self) -> int:
        return struct.calcsize(TYPES[self.type][0]) * 8

    def pack(self, raw: int) -> bytes:
        """The object's bytes for the integer ``raw`` (little-endian, CiA 301)."""
        return struct.pack(TYPES[self.type][0], raw)

    def unpack(self, data: bytes) -> int:
        return struct.unpack(TYPES[self.type][0], data)[0]

    def limits(self) -> tuple[int, int]:
        """The integer range of the type."""
        bits = self.bits
        if self.type.startswith('UNSIGNED'):
            return 0, (1 << bits) - 1
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1

    @property
    def name(self) -> str:
        return f'0x{self.index:04X} sub {self.subindex}'


@dataclass(frozen=True, slots=True)
class FailSafeWrite:
    """One SDO write that sets the output's behaviour on a communication error."""

    index: int
    subindex: int
    type: str
    value: int

    def pack(self) -> bytes:
        return struct.pack(TYPES[self.type][0], self.value)


@dataclass(frozen=True)
class CanopenMapping:
    """The roles of a mapping file (``None``: the role is not mapped)."""

    path: str
    duty: ObjectRef
    enable: ObjectRef | None = None
    current: ObjectRef | None = None
    position: ObjectRef | None = None
    fail_safe: tuple[FailSafeWrite, ...] = ()

    @property
    def rpdo(self) -> tuple[ObjectRef, ...]:
        """Objects in RPDO1, in mapping order."""
        return tuple(o for o in (self.duty, self.enable) if o is not None)

    @property
    def tpdo(self) -> tuple[ObjectRef, ...]:
        """Objects in TPDO1, in mapping order."""
        return tuple(o for o in (self.current, self.position) if o is not None)


def _int(path: str, where: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise MappingError(f'{path}: {where} must be an integer, got {value!r}')
    return value


def _object(path: str, role: str, spec: object) -> ObjectRef:
    if not isinstance(spec, dict):
        raise MappingError(f'{path}: role {role!r} must be a mapping with object, subindex, '
                           f'type, got {spec!r}')
    unknown = set(spec) - {'object', 'subindex', 'type', 'scale', 'pdo', 'on'}
    if unknown:
        raise MappingError(f'{path}: role {role!r}: unknown key(s) {", ".join(sorted(unknown))}')
    for key in ('object', 'subindex', 'type'):
        if key not in spec:
            raise MappingError(f'{path}: role {role!r} has no {key!r}')
    kind = str(spec['type']).upper()
    if kind not in TYPES:
        raise MappingError(f'{path}: role {role!r}: type {spec["type"]!r} is not one of '
                           f'{", ".join(TYPES)}')
    scale = float(spec.get('scale', 1.0))
    if not scale or scale != scale:
        raise MappingError(f'{path}: role {role!r}: scale {spec.get("scale")!r} must be a '
                           'non-zero number')
    pdo = _int(path, f'{role}.pdo', spec.get('pdo', 1))
    if pdo != 1:
        raise MappingError(f'{path}: role {role!r}: pdo {pdo} — the driver maps RPDO1 and '
                           'TPDO1 only')
    return ObjectRef(role, _int(path, f'{role}.object', spec['object']),
                     _int(path, f'{role}.subindex', spec['subindex']), kind, scale, pdo,
                     _int(path, f'{role}.on', spec.get('on', 1)))


def fail_safe_writes(mapping: CanopenMapping) -> tuple[FailSafeWrite, ...]:
    """The output error mode and value writes of a mapping (CiA 401, or its own list).

    Raises
    ------
    MappingError
        The duty object is no CiA 401 output and the mapping lists no ``fail_safe``.
    """
    if mapping.fail_safe:
        return mapping.fail_safe
    writes = []
    for ref in (mapping.duty, mapping.enable):
        if ref is None:
            continue
        if ref.index == 0x6411:      # analog output: error mode 1 = take the error value
            writes += [FailSafeWrite(0x6443, ref.subindex, 'UNSIGNED8', 1),
                       FailSafeWrite(0x6444, ref.subindex, 'INTEGER32', 0)]
        elif ref.index == 0x6200:    # digital outputs: every bit takes its error value 0
            writes += [FailSafeWrite(0x6206, ref.subindex, 'UNSIGNED8', 0xFF),
                       FailSafeWrite(0x6207, ref.subindex, 'UNSIGNED8', 0x00)]
        elif ref.role == 'duty':
            raise MappingError(
                f'{mapping.path}: duty object {ref.name} is no CiA 401 output (0x6411 or '
                '0x6200): list its error mode and value under fail_safe, so the device '
                'de-energises the valve when the host falls silent')
    return tuple(writes)


def load_canopen_mapping(path: str | Path | None = None) -> CanopenMapping:
    """Read a mapping file (default: the CiA 401 mapping).

    Raises
    ------
    MappingError
        Unreadable, not a mapping, no ``duty``, an unknown role or key, a bad type.
    """
    path = Path(path) if path else default_mapping_path()
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise MappingError(f'{path}: cannot read the CANopen mapping: '
                           f'{str(err).splitlines()[0]}') from err
    if not isinstance(data, dict):
        raise MappingError(f'{path}: a CANopen mapping is a YAML mapping of roles')
    unknown = set(data) - set(_ROLES) - {'fail_safe'}
    if unknown:
        raise MappingError(f'{path}: unknown role(s) {", ".join(sorted(map(str, unknown)))}; '
                           f'roles: {", ".join(_ROLES)}, fail_safe')
    if 'duty' not in data:
        raise MappingError(f'{path}: no duty role')
    refs = {role: _object(str(path), role, data[role]) for role in _ROLES if role in data}
    safe = []
    for i, item in enumerate(data.get('fail_safe') or []):
        if not isinstance(item, dict) or {'object', 'subindex', 'type', 'value'} - set(item):
            raise MappingError(f'{path}: fail_safe[{i}] needs object, subindex, type, value')
        kind = str(item['type']).upper()
        if kind not in TYPES:
            raise MappingError(f'{path}: fail_safe[{i}]: type {item["type"]!r} unknown')
        safe.append(FailSafeWrite(_int(str(path), f'fail_safe[{i}].object', item['object']),
                                  _int(str(path), f'fail_safe[{i}].subindex', item['subindex']),
                                  kind, _int(str(path), f'fail_safe[{i}].value', item['value'])))
    mapping = CanopenMapping(str(path), fail_safe=tuple(safe), **refs)
    fail_safe_writes(mapping)   # refuses a duty object without a known error behaviour
    if sum(o.bits for o in mapping.rpdo) > 64 or sum(o.bits for o in mapping.tpdo) > 64:
        raise MappingError(f'{path}: more than 64 bits mapped into one PDO')
    return mapping


def pdo_entry(ref: ObjectRef) -> int:
    """The CiA 301 mapping entry: index (16 bit), sub-index (8), length in bits (8)."""
    return (ref.index << 16) | (ref.subindex << 8) | ref.bits
