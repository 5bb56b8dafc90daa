"""Launch the real-time valve simulator alone.

    ros2 launch valve_model_pkg simulator.launch.py [params_file:=my_valve.yaml]
        [publish_rate_hz:=1000.0] [supply_pressure_pa:=400000.0] [use_sim_time:=false]
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    args = [
        DeclareLaunchArgument('params_file', default_value='',
                              description='Valve parameter YAML (empty: the paper\'s values)'),
        DeclareLaunchArgument('publish_rate_hz', default_value='1000.0',
                              description='valve/state rate [Hz]'),
        DeclareLaunchArgument('supply_pressure_pa', default_value='400000.0',
                              description='Supply pressure, gauge [Pa]'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='Advance the model on /clock'),
    ]
    simulator = Node(
        package='valve_model_pkg', executable='valve_simulator', name='valve_simulator',
        output='screen', emulate_tty=True,
        parameters=[{
            'params_file': LaunchConfiguration('params_file'),
            'publish_rate_hz': LaunchConfiguration('publish_rate_hz'),
            'supply_pressure_pa': LaunchConfiguration('supply_pressure_pa'),
            'use_sim_time': LaunchConfiguration('use_sim_time'),
        }])
    return LaunchDescription(args + [simulator])
