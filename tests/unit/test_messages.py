"""The message definitions: required fields present, every field documents its unit."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from suite_paths import REPO_ROOT

MSG_DIR = REPO_ROOT / 'valve_msgs' / 'msg'
FIELD = re.compile(
    r"^(?P<type>[A-Za-z_][\w/]*(\[\d*\])?)\s+(?P<name>[A-Za-z_]\w*)\s*(?P<rest>.*)$")


def _fields(path: Path) -> dict[str, tuple[str, str]]:
    """name -> (type, comment) for each non-constant field of a .msg file."""
    fields = {}
    for line in path.read_text(encoding='utf-8').splitlines():
        line = line.strip()
        if not line or line.startswith('#'):
            continue
        m = FIELD.match(line)
        assert m, f'{path.name}: cannot parse {line!r}'
        if m['rest'].startswith('='):
            continue  # a constant
        fields[m['name']] = (m['type'], m['rest'].lstrip('#').strip())
    return fields


@pytest.mark.parametrize('msg, required', [
    ('ValveState', {'header', 'coil_voltage', 'coil_current', 'spool_position',
                    'spool_velocity', 'mass_flow', 'duty', 'pwm_frequency', 'supply_pressure',
                    'spool_position_avg'}),
    ('DutyCommand', {'header', 'duty', 'pwm_frequency'}),
    ('FlowCommand', {'header', 'mass_flow'}),
])
def test_required_fields(msg: str, required: set[str]) -> None:
    fields = _fields(MSG_DIR / f'{msg}.msg')
    assert required <= set(fields), required - set(fields)
    assert fields['header'][0] == 'std_msgs/Header'


UNIT = re.compile(r'\[(V|A|m|m/s|kg/s|1|Hz|Pa)\]')


@pytest.mark.parametrize('path', sorted(MSG_DIR.glob('*.msg')), ids=lambda p: p.name)
def test_every_physical_field_states_its_unit(path: Path) -> None:
    for name, (ftype, comment) in _fields(path).items():
        assert comment, f'{path.name}: field {name} has no comment'
        if ftype.startswith('float'):
            assert UNIT.search(comment), f'{path.name}: {name} comment lacks a [unit]: {comment}'
