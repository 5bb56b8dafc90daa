"""package.xml keys resolve with rosdep, every import is declared, setup.py has no dead glob.

A ROS user builds the suite with ``rosdep install --from-paths src --ignore-src`` and
``colcon build``: every key in a package.xml must be one rosdep knows, and every module a
package imports must come from a declared key. The keys below were read in rosdistro
(github.com/ros/rosdistro, commit 8468e88ccd523427f9131e39d2af0938f1c298b2):

- ``rosdep/python.yaml`` for the system and pip keys (Debian/Ubuntu name no package for
  cantools or rosbags, so those resolve through pip: ``python3-cantools-pip``,
  ``python3-rosbags-pip``; ``mcap-ros2-support`` is a pip key whose package requires
  ``mcap``, which has no key of its own);
- ``jazzy/distribution.yaml`` for the ROS packages (released in Jazzy).
"""
from __future__ import annotations

import ast
import glob
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from package_tests import unit_tests_of
from suite_paths import REPO_ROOT

#: rosdistro rosdep/python.yaml (commit 8468e88c), keys with Debian and Ubuntu rules.
ROSDEP_PYTHON_KEYS = frozenset({
    'python3-numpy', 'python3-scipy', 'python3-yaml', 'python3-matplotlib', 'python3-numba',
    'python3-can', 'python3-cantools-pip', 'python3-rosbags-pip', 'python-crccheck-pip',
    'mcap-ros2-support', 'python3-pytest', 'python3-hypothesis', 'python3-setuptools',
    'python3-tqdm', 'python3-pytest-xdist', 'python3-h5py', 'canopen-pip',
    'python3-can-j1939-pip',
})
#: rosdistro jazzy/distribution.yaml (commit 8468e88c): released ROS packages.
JAZZY_PACKAGES = frozenset({
    'rclpy', 'rcl_interfaces', 'rosgraph_msgs', 'builtin_interfaces', 'std_msgs', 'std_srvs',
    'sensor_msgs', 'diagnostic_msgs', 'lifecycle_msgs', 'launch', 'launch_ros',
    'ament_cmake', 'rosidl_default_generators', 'rosidl_default_runtime',
})
SUITE_PACKAGES = ('valve_msgs', 'valve_model_pkg', 'valve_driver_pkg', 'valve_bringup')
PYTHON_PACKAGES = SUITE_PACKAGES[1:]

#: Top-level Python module -> the key that provides it.
IMPORT_KEYS = {
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib', 'numba': 'python3-numba', 'can': 'python3-can',
    'cantools': 'python3-cantools-pip', 'rosbags': 'python3-rosbags-pip',
    'crccheck': 'python-crccheck-pip', 'mcap': 'mcap-ros2-support',
    'mcap_ros2': 'mcap-ros2-support', 'setuptools': 'python3-setuptools',
    'pytest': 'python3-pytest', 'hypothesis': 'python3-hypothesis', 'tqdm': 'python3-tqdm',
    'h5py': 'python3-h5py', 'canopen': 'canopen-pip', 'j1939': 'python3-can-j1939-pip',
    **{name: name for name in JAZZY_PACKAGES | set(SUITE_PACKAGES)},
}
#: Optional modules with no rosdep key in rosdistro (commit 8468e88c): imported lazily, only
#: by the fleet identification (valve_identify_batch), the live view (foxglove) or the TDMS
#: import (nptdms), installed with pip from
#: requirements/python.txt; valve_model_pkg/package.xml says so in a comment.
PIP_ONLY_OPTIONAL = {'dask', 'distributed', 'pyarrow',
                     'foxglove',  # foxglove-sdk: valve_bringup's live view (no key)
                     'nptdms'}  # npTDMS: instruments.tdms, imported when a TDMS file is read
# Modules the tests import from the tests/ folder itself.
LOCAL_TEST_MODULES = {p.stem for p in (REPO_ROOT / 'tests').glob('*.py')} | {
    p.name for p in (REPO_ROOT / 'tests').iterdir() if (p / '__init__.py').is_file()} | {
    'tests'}


def _manifest(package: str) -> ET.Element:
    return ET.parse(REPO_ROOT / package / 'package.xml').getroot()


def _keys(package: str, kinds: tuple[str, ...] | None = None) -> set[str]:
    return {e.text.strip() for e in _manifest(package)
            if e.tag.endswith('depend') and e.text and (kinds is None or e.tag in kinds)}


def _imports(paths: list[Path]) -> dict[str, list[str]]:
    """Third-party top-level modules imported anywhere in the files -> files importing it."""
    found: dict[str, list[str]] = {}
    for path in paths:
        tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name.split('.')[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module.split('.')[0]]
            for name in names:
                if name not in sys.stdlib_module_names and name != '__future__':
                    found.setdefault(name, []).append(str(path.relative_to(REPO_ROOT)))
    return found


def _package_files(package: str) -> list[Path]:
    root = REPO_ROOT / package
    return sorted(p for p in root.rglob('*.py') if '__pycache__' not in p.parts)


def _keys_available_to(package: str) -> set[str]:
    """Keys of the package and of every suite package below it (rosdep installs those)."""
    below = SUITE_PACKAGES[:SUITE_PACKAGES.index(package) + 1]
    return set().union(*(_keys(p) for p in below)) | set(below)


@pytest.mark.parametrize('package', SUITE_PACKAGES)
def test_manifest_is_format_3_and_every_key_resolves(package: str) -> None:
    root = _manifest(package)
    assert root.get('format') == '3'
    assert root.findtext('name') == package
    unknown = _keys(package) - ROSDEP_PYTHON_KEYS - JAZZY_PACKAGES - set(SUITE_PACKAGES)
    assert not unknown, (f'{package}/package.xml: keys rosdep does not know: '
                         f'{sorted(unknown)} (check rosdistro rosdep/*.yaml)')


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_every_import_of_a_package_is_declared(package: str) -> None:
    keys = _keys(package)
    missing = {}
    for module, files in _imports(_package_files(package)).items():
        if module == package or module in PIP_ONLY_OPTIONAL:
            continue
        key = IMPORT_KEYS.get(module)
        if key is None or key not in keys:
            missing[module] = (key or 'NO KNOWN KEY', files[:3])
    assert not missing, f'{package}/package.xml lacks keys for imports: {missing}'


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_every_import_of_a_package_s_tests_is_declared(package: str) -> None:
    keys = _keys_available_to(package)
    missing = {}
    for module, files in _imports(unit_tests_of(package)).items():
        if module in LOCAL_TEST_MODULES:
            continue
        key = IMPORT_KEYS.get(module)
        if key is None or key not in keys:
            missing[module] = (key or 'NO KNOWN KEY', files[:3])
    assert not missing, f'{package}/package.xml lacks (test_)depend keys: {missing}'


def _setup_call(package: str) -> ast.Call:
    tree = ast.parse((REPO_ROOT / package / 'setup.py').read_text(encoding='utf-8'))
    return next(n for n in ast.walk(tree)
                if isinstance(n, ast.Call) and getattr(n.func, 'id', '') == 'setup')


def _keyword(call: ast.Call, name: str) -> ast.AST | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def _strings(node: ast.AST | None) -> list[str]:
    return [n.value for n in ast.walk(node) if isinstance(n, ast.Constant)
            and isinstance(n.value, str)] if node is not None else []


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_setup_py_has_no_dead_glob_or_missing_data_file(package: str) -> None:
    root = REPO_ROOT / package
    call = _setup_call(package)
    data_files = _keyword(call, 'data_files')
    for node in ast.walk(data_files):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'glob':
            pattern = node.args[0].value
            assert glob.glob(str(root / pattern)), f'{package}/setup.py: dead glob {pattern!r}'
    for entry in data_files.elts:  # (destination, [files]) pairs
        files = entry.elts[1]
        if isinstance(files, ast.List):  # literal file lists (the globs are checked above)
            for element in files.elts:
                name = eval(compile(ast.Expression(element), 'setup.py', 'eval'),
                            {'package_name': package})
                assert (root / name).is_file(), f'{package}/setup.py: no file {name}'
    package_data = _keyword(call, 'package_data')
    if package_data is not None:
        for patterns in package_data.values:
            pkg_dir = root / package  # the only Python package key used here
            for pattern in _strings(patterns):
                assert glob.glob(str(pkg_dir / pattern)), \
                    f'{package}/setup.py: dead package_data glob {pattern!r}'


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_console_scripts_point_at_a_main(package: str) -> None:
    scripts = _strings(_keyword(_setup_call(package), 'entry_points'))
    for spec in scripts:
        if '=' not in spec:
            continue
        target = spec.split('=', 1)[1].strip()
        module, _, attr = target.partition(':')
        path = REPO_ROOT / package / Path(*module.split('.'))
        path = path.with_suffix('.py') if path.with_suffix('.py').is_file() else \
            path / '__init__.py'
        assert path.is_file(), f'{spec}: no module {module}'
        tree = ast.parse(path.read_text(encoding='utf-8'))
        defined = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef,
                                                               ast.ClassDef))}
        assert attr in defined, f'{spec}: {module} defines no {attr}'


@pytest.mark.parametrize('package', PYTHON_PACKAGES)
def test_colcon_test_finds_pytest_and_the_package_tests(package: str) -> None:
    """`colcon test` runs pytest only if setup.py names it as a test dependency."""
    extras = _keyword(_setup_call(package), 'extras_require')
    assert 'pytest' in _strings(extras)
    assert 'python3-pytest' in _keys(package, ('test_depend',))
    assert (REPO_ROOT / package / 'test' / 'test_repository_tests.py').is_file()
