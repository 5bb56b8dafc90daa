"""The set-up: the wheel path fix and the refusal of an unsupported Python."""
from __future__ import annotations

import os
import stat
import subprocess
import sys
import sysconfig

from suite_paths import REPO_ROOT

FIX = REPO_ROOT / 'scripts' / 'fix_wheel_paths.py'


def test_wheel_path_fix_rewrites_build_machine_paths_once(tmp_path) -> None:
    cmake = tmp_path / 'share' / 'std_msgs' / 'cmake' / 'export_py.cmake'
    cmake.parent.mkdir(parents=True)
    cmake.write_text('INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11;'
                     '/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"\n')
    untouched = tmp_path / 'share' / 'other.cmake'
    untouched.write_text('set(X 1)\n')
    first = subprocess.run([sys.executable, str(FIX), str(tmp_path)], capture_output=True,
                           text=True, check=True)
    assert 'rewrote 1 CMake file' in first.stdout
    text = cmake.read_text()
    assert '/opt/python' not in text
    assert sysconfig.get_paths()['include'] in text
    assert str(tmp_path / 'lib' / 'python3.11' / 'site-packages' / 'numpy') in text
    assert untouched.read_text() == 'set(X 1)\n'
    second = subprocess.run([sys.executable, str(FIX), str(tmp_path)], capture_output=True,
                            text=True, check=True)
    assert 'rewrote 0 CMake file' in second.stdout


def test_setup_refuses_an_unsupported_python_and_names_the_supported_one(tmp_path) -> None:
    fake = tmp_path / 'python3.9'
    fake.write_text('#!/bin/sh\necho 3.9\n')
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    env = dict(os.environ, PYTHON=str(fake), VALVE_VENV=str(tmp_path / 'venv'))
    out = subprocess.run(['bash', str(REPO_ROOT / 'scripts' / 'setup.sh')], env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode != 0
    assert 'unsupported Python' in out.stderr
    assert '3.11' in out.stderr
    assert not (tmp_path / 'venv').exists()


def test_env_bash_gives_a_working_suite_shell() -> None:
    script = (f'source {REPO_ROOT / "ros2_ws" / "env.bash"} && '
              'echo "range=$ROS_AUTOMATIC_DISCOVERY_RANGE" && '
              'echo "profile=$FASTRTPS_DEFAULT_PROFILES_FILE" && command -v valve_simulator && '
              'python -c "import valve_msgs.msg, valve_model_pkg; print(\'imports ok\')"')
    out = subprocess.run(['bash', '-c', script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    # DDS stays on the machine: the loopback-only Fast DDS profile, with the range that
    # leaves its transports alone (docs/safety.md, "Network"; LOCALHOST would add a
    # transport bound beyond loopback).
    assert 'range=SYSTEM_DEFAULT' in out.stdout
    assert f'profile={REPO_ROOT / "ros2_ws" / "fastdds_localhost.xml"}' in out.stdout
    assert 'imports ok' in out.stdout
