"""`colcon test` of valve_bringup: the repository's unit tests of this package.

Which tests belong to which package, and how they run, is said once, in the repository's
``tests/package_tests.py`` (:func:`check_package`).
"""
from __future__ import annotations

import runpy
from pathlib import Path

import pytest

PACKAGE = 'valve_bringup'
# <repo>/<package>/test/this file (colcon may reach it through ros2_ws/src/ symlinks).
MAPPING = Path(__file__).resolve().parents[2] / 'tests' / 'package_tests.py'


def test_repository_unit_tests_of_this_package_pass() -> None:
    if not MAPPING.is_file():
        pytest.skip(f'no repository tests around {PACKAGE} ({MAPPING} missing)')
    runpy.run_path(str(MAPPING))['check_package'](PACKAGE)
