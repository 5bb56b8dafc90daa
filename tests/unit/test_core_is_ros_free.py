"""The physics, numerics, identification, map, protocol and emulator cores must not need ROS."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from suite_paths import REPO_ROOT

CORE_DIRS = [
    REPO_ROOT / 'valve_model_pkg' / 'valve_model_pkg' / name
    for name in ('model', 'maps', 'identification', 'pneumatics', 'recording', 'cli',
                 'dataformat', 'analysis')
] + [
    REPO_ROOT / 'valve_driver_pkg' / 'valve_driver_pkg' / name
    for name in ('protocol', 'emulator', 'driver', 'canbus', 'devices', 'standins',
                 'replay.py')
] + [
    # What starts the suite: the process supervisor and the CAN backend's command lines.
    REPO_ROOT / 'valve_bringup' / 'valve_bringup' / name
    for name in ('supervisor.py', 'backend.py')
]

ROS_MODULES = ('rclpy', 'rcl_interfaces', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs',
               'valve_msgs', 'lifecycle_msgs', 'builtin_interfaces')


def _core_files() -> list[Path]:
    files: list[Path] = []
    for path in CORE_DIRS:
        if path.is_file():
            files.append(path)
        elif path.is_dir():
            files.extend(sorted(path.rglob('*.py')))
    return files


def _top_level_imports(path: Path) -> set[str]:
    """Modules imported at module level (imports inside functions may be lazy on purpose)."""
    tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.Import):
            names.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split('.')[0])
    return names


def test_core_files_exist() -> None:
    assert len(_core_files()) >= 3


@pytest.mark.parametrize('path', _core_files(), ids=lambda p: str(p.relative_to(REPO_ROOT)))
def test_core_module_does_not_import_ros_at_module_level(path: Path) -> None:
    offending = _top_level_imports(path) & set(ROS_MODULES)
    assert not offending, f'{path} imports {sorted(offending)}'


def test_importing_the_cores_loads_no_ros_module() -> None:
    code = (
        'import sys, importlib, pkgutil\n'
        'sys.path[:0] = [%r, %r, %r]\n'
        'import valve_model_pkg, valve_driver_pkg, valve_bringup\n'
        'for pkg in ("valve_model_pkg.model", "valve_model_pkg.maps",\n'
        '            "valve_model_pkg.identification", "valve_model_pkg.pneumatics",\n'
        '            "valve_model_pkg.recording", "valve_model_pkg.analysis",\n'
        '            "valve_driver_pkg.protocol", "valve_driver_pkg.emulator",\n'
        '            "valve_driver_pkg.driver", "valve_driver_pkg.canbus",\n'
        '            "valve_driver_pkg.devices", "valve_driver_pkg.standins",\n'
        '            "valve_driver_pkg.replay",\n'
        '            "valve_bringup.supervisor", "valve_bringup.backend"):\n'
        '    try:\n'
        '        m = importlib.import_module(pkg)\n'
        '    except ModuleNotFoundError as e:\n'
        '        if e.name == pkg: continue\n'
        '        raise\n'
        '    for info in pkgutil.walk_packages(getattr(m, "__path__", []), pkg + "."):\n'
        '        importlib.import_module(info.name)\n'
        'ros = sorted(n for n in sys.modules if n.split(".")[0] in %r)\n'
        'print(",".join(ros))\n'
    ) % (str(REPO_ROOT / 'valve_model_pkg'), str(REPO_ROOT / 'valve_driver_pkg'),
         str(REPO_ROOT / 'valve_bringup'), ROS_MODULES)
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '', f'ROS modules loaded by the cores: {out.stdout}'
