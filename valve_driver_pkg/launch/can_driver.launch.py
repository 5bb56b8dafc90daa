"""Launch valve_can_driver alone, for a real valve controller.

    ros2 launch valve_driver_pkg can_driver.launch.py                       # socketcan can0
    ros2 launch valve_driver_pkg can_driver.launch.py channel:=can1 node_id:=3
    ros2 launch valve_driver_pkg can_driver.launch.py autostart:=false      # manage it:
    ros2 lifecycle set /valve_can_driver configure   (then: activate, deactivate, cleanup)

Bring the SocketCAN interface up first (the bitrate is the kernel's, not a parameter):
``sudo ip link set can0 type can bitrate 500000 restart-ms 100 && sudo ip link set can0 up``.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from valve_driver_pkg.driver.config import DriverConfig

#: The driver's defaults are DriverConfig's (written once); this file only repeats none.
DEFAULTS = DriverConfig()


def generate_launch_description() -> LaunchDescription:
    cfg = LaunchConfiguration
    args = [
        DeclareLaunchArgument('interface', default_value=DEFAULTS.interface,
                              description='python-can interface'),
        DeclareLaunchArgument('channel', default_value=DEFAULTS.channel,
                              description='CAN channel'),
        DeclareLaunchArgument('bitrate', default_value=str(DEFAULTS.bitrate),
                              description='Bit rate for adapters that set it [bit/s]'),
        DeclareLaunchArgument('node_id', default_value=str(DEFAULTS.node_id),
                              description='Controller node id 0..15 (ids 0x680 + ...)'),
        DeclareLaunchArgument('params_file', default_value='',
                              description='Valve parameter YAML for the orifice equation'),
        DeclareLaunchArgument('command_timeout_s',
                              default_value=str(DEFAULTS.command_timeout_s),
                              description='Watchdog: no duty command this long -> duty 0 [s]'),
        DeclareLaunchArgument('autostart', default_value='true',
                              description='Configure and activate at start-up'),
    ]
    driver = Node(
        package='valve_driver_pkg', executable='valve_can_driver', name='valve_can_driver',
        output='screen', emulate_tty=True,
        parameters=[{
            'interface': cfg('interface'), 'channel': cfg('channel'),
            'bitrate': cfg('bitrate'), 'node_id': cfg('node_id'),
            'params_file': cfg('params_file'), 'command_timeout_s': cfg('command_timeout_s'),
            'autostart': cfg('autostart'),
        }])
    return LaunchDescription(args + [driver])
