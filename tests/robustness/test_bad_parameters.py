"""Bad parameter files: one line naming file, line, key and value; nothing reaches the kernel.

Binary and non-UTF-8 files, duplicate keys, YAML 1.2 numbers, physically
implausible values (refused, or accepted with a warning under ``--allow-implausible``).
"""
from __future__ import annotations

import logging
import shutil
import subprocess
from pathlib import Path

import pytest

from valve_model_pkg.model import ParameterError, ValveParameters, default_parameters_path
from valve_model_pkg.model.parameters import (MAX_PARAMETER_FILE_BYTES, PLAUSIBLE_RANGES,
                                              PARAMETER_FIELDS, load_parameters)

GOOD = default_parameters_path().read_text(encoding='utf-8')


def _with(tmp_path: Path, key: str, value: str, name: str = 'p.yaml') -> Path:
    """The packaged file with one value replaced (the line of ``key`` kept)."""
    lines = GOOD.splitlines()
    for i, line in enumerate(lines):
        if line.strip().startswith(f'{key}:'):
            indent = line[:len(line) - len(line.lstrip())]
            lines[i] = f'{indent}{key}: {value}'
            path = tmp_path / name
            path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
            return path
    raise AssertionError(key)


def _line_of(path: Path, key: str) -> int:
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip().startswith(f'{key}:'):
            return n
    raise AssertionError(key)


def test_every_parameter_has_a_plausible_range_holding_the_paper_value() -> None:
    assert set(PLAUSIBLE_RANGES) == set(PARAMETER_FIELDS)
    paper = ValveParameters()
    for name, (lo, hi) in PLAUSIBLE_RANGES.items():
        assert lo <= getattr(paper, name) <= hi, name


@pytest.mark.parametrize('text', ['27e-3', '2.7E-2', '+27e-3'])
def test_yaml_1_2_numbers_are_numbers(tmp_path: Path, text: str) -> None:
    assert load_parameters(_with(tmp_path, 'spool_mass_kg', text)).spool_mass_kg == 0.027


@pytest.mark.parametrize('key, value, what', [
    ('spool_mass_kg', '1.0e-300', 'outside the numerically safe range'),
    ('spool_mass_kg', '1e-300', 'outside the numerically safe range'),
    ('spring_stiffness_n_per_m', '1e300', 'outside the numerically safe range'),
    ('coil_turns', '1e12', 'outside the numerically safe range'),
    ('spool_mass_kg', '1000', 'physically implausible'),
    ('coil_resistance_ohm', '1e-300', 'outside the numerically safe range'),
])
def test_implausible_values_are_refused_naming_file_line_key_value(
        tmp_path: Path, key: str, value: str, what: str) -> None:
    path = _with(tmp_path, key, value)
    with pytest.raises(ParameterError) as info:
        load_parameters(path)
    msg = str(info.value)
    assert msg.startswith(f'{path}:{_line_of(path, key)}: {key} = ')
    assert what in msg and '\n' not in msg
    lo, hi = PLAUSIBLE_RANGES[key]
    assert f'{lo:g}' in msg and f'{hi:g}' in msg  # the range is named


def test_allow_implausible_accepts_with_a_warning_but_never_unsafe_values(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    heavy = _with(tmp_path, 'spool_mass_kg', '1000', 'heavy.yaml')
    with caplog.at_level(logging.WARNING):
        assert load_parameters(heavy, allow_implausible=True).spool_mass_kg == 1000.0
    assert any('spool_mass_kg = 1000.0' in r.getMessage() and 'plausible' in r.getMessage()
               for r in caplog.records)
    for key, value in (('spool_mass_kg', '1e-300'), ('coil_turns', '1e12'),
                       ('spring_stiffness_n_per_m', '1e300')):
        with pytest.raises(ParameterError, match='numerically safe range'):
            load_parameters(_with(tmp_path, key, value), allow_implausible=True)
    # and the model refuses such values whichever way they come (never reach the kernel)
    with pytest.raises(ParameterError, match='spool_mass_kg'):
        ValveParameters().replace(spool_mass_kg=1e-300)


def test_duplicate_key_is_refused_naming_both_lines(tmp_path: Path) -> None:
    path = tmp_path / 'dup.yaml'
    path.write_text(GOOD.replace('  coil_turns: 1250.0', '  coil_turns: 1250.0\n'
                                 '  spool_mass_kg: 0.03'), encoding='utf-8')
    first = _line_of(path, 'spool_mass_kg')
    second = first + 3  # after spring and coil turns
    with pytest.raises(ParameterError) as info:
        load_parameters(path)
    assert str(info.value) == (f"{path}:{second}: duplicate key 'spool_mass_kg' (first on "
                               f'line {first}); a key may be given once')


@pytest.mark.parametrize('content, what', [
    (b'\x00\x01\x02binary' * 100, 'binary file'),
    (b'valve:\n  spool_mass_kg: 0.027 \xff\xfe\n', 'not UTF-8'),
    (b'valve: [1, 2\n', 'not valid YAML'),
    (b'[' * 100_000, 'not'),
    (b'valve: {a: 1, ', 'not valid YAML'),
])
def test_binary_non_utf8_and_broken_files_get_one_line(tmp_path: Path, content: bytes,
                                                       what: str) -> None:
    path = tmp_path / 'bad.yaml'
    path.write_bytes(content)
    with pytest.raises(ParameterError) as info:
        load_parameters(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and what in msg and '\n' not in msg


def test_a_huge_file_is_refused_before_reading(tmp_path: Path) -> None:
    path = tmp_path / 'huge.yaml'
    with open(path, 'wb') as fh:
        fh.truncate(MAX_PARAMETER_FILE_BYTES + 1)  # sparse: nothing written
    with pytest.raises(ParameterError, match=f'at most {MAX_PARAMETER_FILE_BYTES} bytes'):
        load_parameters(path)


def _script(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.fail(f'{name} not on PATH; source ros2_ws/env.bash')
    return path


@pytest.mark.parametrize('command', [
    ['valve_simulate', '-o', 'OUT/x.csv', '--no-plot', '--params'],
    ['valve_map', '-o', 'OUT/m.json', '--no-figures', '--params'],
])
def test_allow_implausible_flag_on_the_commands(tmp_path: Path, command: list[str]) -> None:
    heavy = _with(tmp_path, 'spool_mass_kg', '1000', 'heavy.yaml')
    argv = [_script(command[0])] + [a.replace('OUT', str(tmp_path)) for a in command[1:]]
    refused = subprocess.run(argv + [str(heavy)], capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and 'physically implausible' in refused.stderr
    assert '--allow-implausible' in subprocess.run(
        [argv[0], '--help'], capture_output=True, text=True, timeout=60).stdout
