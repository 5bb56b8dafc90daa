"""`--help` of every console script (read from every setup.py) exits 0 and says how to use it.

The nodes print their parameters (type, default, range, description) from their own
declarations, without a running ROS graph and without starting any work (the CAN driver
opens no bus, the recorder leaves no bag behind).
"""
from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from suite_paths import console_scripts

NODES = {'valve_simulator', 'flow_to_duty', 'pneumatic_cylinder', 'position_controller',
         'valve_recorder', 'valve_can_driver', 'valve_lockstep_sim', 'valve_bank_simulator'}


def test_the_list_is_complete() -> None:
    scripts = set(console_scripts())
    assert NODES <= scripts
    assert {'valve_demo', 'valve_bench_loop', 'valve_simulate', 'valve_map',
            'valve_identify', 'valve_controller_emulator'} <= scripts


@pytest.mark.node
@pytest.mark.parametrize('script', console_scripts())
def test_help_exits_0_and_describes_the_command(script: str, tmp_path) -> None:
    exe = shutil.which(script)
    assert exe, f'{script} is not on PATH (source ros2_ws/env.bash)'
    out = subprocess.run([exe, '--help'], capture_output=True, text=True, timeout=120,
                         cwd=tmp_path, env=dict(os.environ, PYTHONUNBUFFERED='1'))
    assert out.returncode == 0, out.stdout + out.stderr
    assert 'usage' in out.stdout.lower(), out.stdout
    assert 'Traceback' not in out.stderr, out.stderr
    if script in NODES:
        assert 'parameters' in out.stdout, out.stdout
        assert 'default' in out.stdout and 'range [' in out.stdout, out.stdout
        assert 'exit codes' in out.stdout
    assert not list(tmp_path.iterdir()), f'{script} --help left files behind'
