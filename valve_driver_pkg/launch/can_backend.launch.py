"""Launch the CAN backend: controller emulator + CAN driver (replaces valve_simulator).

    ros2 launch valve_driver_pkg can_backend.launch.py
    ros2 launch valve_driver_pkg can_backend.launch.py effect:=coil_heating
    ros2 launch valve_driver_pkg can_backend.launch.py interface:=socketcan channel:=can0 \\
        emulator:=false        # a real controller on can0

The emulator hosts the tcp_loopback hub (127.0.0.1 only) the driver connects to; with
socketcan both ends use the kernel's bus (vcan0 or a real adapter). valve/state and
valve/duty_command are the same topics and types as valve_simulator's.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.conditions import IfCondition
from launch.substitutions import (LaunchConfiguration, PathJoinSubstitution,
                                  PythonExpression)
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackagePrefix


def generate_launch_description() -> LaunchDescription:
    cfg = LaunchConfiguration
    args = [
        DeclareLaunchArgument('interface', default_value='tcp_loopback',
                              description='python-can interface (tcp_loopback, socketcan, ...)'),
        DeclareLaunchArgument('channel', default_value='127.0.0.1:29536',
                              description='Channel (HOST:PORT for tcp_loopback, can0, vcan0)'),
        DeclareLaunchArgument('node_id', default_value='0', description='Controller node id'),
        DeclareLaunchArgument('params_file', default_value='',
                              description='Valve parameter YAML (empty: the paper\'s values)'),
        DeclareLaunchArgument('telemetry_rate_hz', default_value='1000.0',
                              description='Emulator telemetry rate = valve/state rate [Hz]'),
        DeclareLaunchArgument('command_timeout_s', default_value='0.5',
                              description='Driver watchdog: no duty command this long -> 0'),
        DeclareLaunchArgument('emulator', default_value='true',
                              description='Start valve_controller_emulator (false: hardware)'),
        DeclareLaunchArgument('effect', default_value='',
                              description='Physical effect the emulated valve has and the '
                                          'nominal model lacks (e.g. coil_heating)'),
    ]
    emulator_exe = PathJoinSubstitution([FindPackagePrefix('valve_driver_pkg'), 'lib',
                                         'valve_driver_pkg', 'valve_controller_emulator'])
    emulator_cmd = [emulator_exe, '--interface', cfg('interface'), '--channel', cfg('channel'),
                    '--node-id', cfg('node_id'), '--params-file', cfg('params_file'),
                    '--telemetry-rate-hz', cfg('telemetry_rate_hz')]

    def when(effect_test: str) -> IfCondition:
        # emulator:=true|false as launch spells booleans; effect empty or not.
        return IfCondition(PythonExpression([
            "'", cfg('emulator'), "'.lower() in ('true', '1') and '", cfg('effect'), "' ",
            effect_test]))

    emulator = ExecuteProcess(cmd=emulator_cmd, name='valve_controller_emulator',
                              output='screen', condition=when("== ''"))
    emulator_with_effect = ExecuteProcess(
        cmd=emulator_cmd + ['--effect', cfg('effect')], name='valve_controller_emulator',
        output='screen', condition=when("!= ''"))
    driver = Node(
        package='valve_driver_pkg', executable='valve_can_driver', name='valve_can_driver',
        output='screen', emulate_tty=True,
        parameters=[{
            'interface': cfg('interface'), 'channel': cfg('channel'),
            'node_id': cfg('node_id'), 'params_file': cfg('params_file'),
            'telemetry_rate_hz': cfg('telemetry_rate_hz'),
            'command_timeout_s': cfg('command_timeout_s'), 'autostart': True,
        }])
    return LaunchDescription(args + [emulator, emulator_with_effect, driver])
