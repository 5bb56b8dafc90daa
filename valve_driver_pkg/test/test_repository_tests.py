"""`colcon test` of valve_driver_pkg: runs the repository's unit tests of this package.

The suite's tests live in the repository's ``tests/``; ``tests/package_tests.py`` says which
belong to which package (README, "Tests and packages"). They run in a pytest of their own
from the repository root, so its ``pytest.ini`` and ``conftest.py`` apply exactly as in
``make test``. A package copied alone into another workspace has no repository around it:
then there is nothing to run and the test is skipped.
"""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = 'valve_driver_pkg'
# <repo>/valve_driver_pkg/test/this file (colcon may reach it through ros2_ws/src/ symlinks).
REPO_ROOT = Path(__file__).resolve().parents[2]
MAPPING = REPO_ROOT / 'tests' / 'package_tests.py'


def test_repository_unit_tests_of_this_package_pass() -> None:
    if not MAPPING.is_file():
        pytest.skip(f'no repository tests around {PACKAGE} ({MAPPING} missing)')
    spec = importlib.util.spec_from_file_location('valve_package_tests', MAPPING)
    mapping = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mapping)
    files = [str(p.relative_to(REPO_ROOT)) for p in mapping.unit_tests_of(PACKAGE)]
    assert files, f'no unit tests listed for {PACKAGE} in {MAPPING}'
    out = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                          *files], cwd=REPO_ROOT, capture_output=True, text=True)
    # pytest's own summary is the useful part of a failure.
    assert out.returncode == 0, out.stdout[-6000:] + out.stderr[-2000:]
