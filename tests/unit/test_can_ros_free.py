"""The CAN driver's cores import no ROS: protocol, transport, driver logic, emulator.

(The CAN backend as processes moved to valve_bringup.backend: test_core_is_ros_free.)
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]

CORES = ('valve_driver_pkg.protocol', 'valve_driver_pkg.canbus', 'valve_driver_pkg.driver',
         'valve_driver_pkg.emulator', 'valve_driver_pkg.emulator.emulator_main',
         'valve_driver_pkg.errors', 'valve_driver_pkg.devices.core',
         'valve_driver_pkg.standins.canopen_device', 'valve_driver_pkg.standins.j1939_device',
         'valve_driver_pkg.standins.dbc_device', 'valve_driver_pkg.replay')
ROS = ('rclpy', 'rcl_interfaces', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'valve_msgs',
       'lifecycle_msgs', 'builtin_interfaces')


def test_cores_import_without_ros() -> None:
    code = (f'import sys; sys.path[:0] = {[str(REPO_ROOT / "valve_driver_pkg"), str(REPO_ROOT / "valve_model_pkg")]!r}\n'  # noqa: E501
            f'import importlib\n'
            f'for m in {CORES!r}: importlib.import_module(m)\n'
            f'print(sorted(m for m in sys.modules if m.split(".")[0] in {ROS!r}))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == '[]', f'ROS modules imported by the cores: {out}'
