"""The CLI rule of the model package's commands, run as the installed console scripts.

``-o/--out`` names the output; exit 0 on success, 2 for refused input (one line naming the
file, no traceback), 1 for a failure inside.
"""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

MISSING = '/nonexistent/valve_cli_rule_input'

#: console script -> argv with a nonexistent input file (any output into OUT)
COMMANDS = {
    'valve_simulate': ['--params', f'{MISSING}.yaml', '-o', 'OUT/x.csv', '--no-plot'],
    'valve_identify': ['--fit', f'{MISSING}.csv', '-o', 'OUT/ident'],
    'valve_flow_check': [f'{MISSING}.csv', '-o', 'OUT/cmp.json'],
    'valve_map': ['--show', f'{MISSING}.json', '--no-figures'],
    'valve_report': [MISSING, '-o', 'OUT/report'],
    'valve_recorder': ['--info', MISSING],
    'valve_identify_batch': [f'{MISSING}.csv', '-o', 'OUT/fleet'],
    'valve_import': [f'{MISSING}.csv', '--voltage', 'CH1', '--current', 'CH2', '-o',
                     'OUT/rec.csv'],
}


def _script(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.fail(f'console script {name} not on PATH; build the workspace and source '
                    'ros2_ws/env.bash')
    return path


def _run(argv: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    argv = [a.replace('OUT', str(tmp_path)) for a in argv]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL)


@pytest.mark.parametrize('name', sorted(COMMANDS))
def test_help_exits_0_and_names_the_output_option(name: str, tmp_path: Path) -> None:
    proc = _run([_script(name), '--help'], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert 'usage' in proc.stdout.lower()
    assert '-o' in proc.stdout and '--out' in proc.stdout, proc.stdout
    assert 'Traceback' not in proc.stderr


@pytest.mark.parametrize('name', sorted(COMMANDS))
def test_a_missing_input_file_exits_2_with_one_line(name: str, tmp_path: Path) -> None:
    proc = _run([_script(name)] + COMMANDS[name], tmp_path)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert MISSING in lines[0] and lines[0].startswith(f'{name}: ')
    assert 'Traceback' not in proc.stderr
    assert not any(tmp_path.iterdir())  # nothing written for refused input
