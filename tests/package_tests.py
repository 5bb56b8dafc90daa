"""Which of the repository's tests belong to which package (one place for that fact).

The suite's tests live here, in ``tests/`` (``unit/``: ROS-free cores and the repository's
own checks, ``node/``: real node processes, ``e2e/``: what the README tells a user to run).
``make test`` runs all of them. ``colcon test`` runs, per ament_python package, that
package's unit tests listed here: each package's ``test/test_repository_tests.py`` calls
:func:`check_package`, which runs them from the repository root. Node and end-to-end tests
need the whole built suite on ``PATH`` (``source ros2_ws/env.bash``), so they run with
``make test`` only. ``tests/unit/test_package_tests.py`` checks that every unit test file
belongs to exactly one package.
"""
from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
UNIT_DIR = REPO_ROOT / 'tests' / 'unit'

#: Unit test files of each package other than valve_model_pkg (file name patterns).
#: valve_model_pkg owns every other unit test file (model, maps, identification,
#: pneumatics, recording, data format, its CLIs).
_CLAIMED = {
    # ament_cmake, built with BUILD_TESTING=OFF: its test runs with `make test` only.
    'valve_msgs': ('test_messages.py',),
    'valve_driver_pkg': ('test_can_*.py',),
    # The top of the package graph holds the checks of the whole repository.
    'valve_bringup': ('test_supervisor.py', 'test_setup.py', 'test_core_is_ros_free.py',
                      'test_package_graph.py', 'test_package_xml.py',
                      'test_package_tests.py', 'test_bench_loop_*.py',
                      'test_bench_step_check.py'),
}
PACKAGES = ('valve_msgs', 'valve_model_pkg', 'valve_driver_pkg', 'valve_bringup')


def _claimed(package: str) -> set[Path]:
    return {p for pattern in _CLAIMED.get(package, ()) for p in UNIT_DIR.glob(pattern)}


def unit_tests_of(package: str) -> list[Path]:
    """The unit test files of ``package`` (sorted; empty for an unknown package)."""
    if package == 'valve_model_pkg':
        others = set().union(*(_claimed(p) for p in _CLAIMED))
        return sorted(set(UNIT_DIR.glob('test_*.py')) - others)
    return sorted(_claimed(package))


def run_unit_tests_of(package: str) -> tuple[int, str]:
    """Run ``package``'s unit tests in a pytest of their own from the repository root.

    Returns the exit status and the tail of pytest's output (its summary is the useful
    part of a failure). Each package's ``test/test_repository_tests.py`` calls this, so
    ``colcon test`` and ``make test`` read the same ``pytest.ini`` and ``conftest.py``.
    """
    import subprocess
    import sys
    files = [str(p.relative_to(REPO_ROOT)) for p in unit_tests_of(package)]
    if not files:
        return 1, f'no unit tests listed for {package} in {__file__}'
    out = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                          *files], cwd=REPO_ROOT, capture_output=True, text=True)
    return out.returncode, out.stdout[-6000:] + out.stderr[-2000:]


def check_package(package: str) -> None:
    """Run ``package``'s unit tests (:func:`run_unit_tests_of`); the test of each package.

    A package's ``test/test_repository_tests.py`` loads this file by its path (a package
    copied alone into another workspace has no repository around it: it skips) and calls
    this, so the three packages' ``colcon test`` share one body.

    Raises
    ------
    AssertionError
        The tests failed; the message is the tail of pytest's output.
    """
    status, output = run_unit_tests_of(package)
    if status != 0:
        raise AssertionError(f'unit tests of {package}: pytest exit {status}\n{output}')
