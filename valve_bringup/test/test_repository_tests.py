"""`colcon test` of valve_bringup: runs the repository's unit tests of this package.

The suite's tests live in the repository's ``tests/``; ``tests/package_tests.py`` says which
belong to which package (README, "Tests and packages"). They run in a pytest of their own
from the repository root, so its ``pytest.ini`` and ``conftest.py`` apply exactly as in
``make test``. A package copied alone into another workspace has no repository around it:
then there is nothing to run and the test is skipped.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

PACKAGE = 'valve_bringup'
# <repo>/valve_bringup/test/this file (colcon may reach it through ros2_ws/src/ symlinks).
REPO_ROOT = Path(__file__).resolve().parents[2]
MAPPING = REPO_ROOT / 'tests' / 'package_tests.py'


def test_repository_unit_tests_of_this_package_pass() -> None:
    if not MAPPING.is_file():
        pytest.skip(f'no repository tests around {PACKAGE} ({MAPPING} missing)')
    spec = importlib.util.spec_from_file_location('valve_package_tests', MAPPING)
    mapping = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mapping)
    status, output = mapping.run_unit_tests_of(PACKAGE)
    assert status == 0, output
