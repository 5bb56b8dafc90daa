"""Launch the flow-to-duty converter alone.

    ros2 launch valve_model_pkg flow_to_duty.launch.py [map_file:=my_map.json]
        [params_file:=my_valve.yaml] [pwm_frequency_hz:=50.0] [supply_pressure_pa:=400000.0]
        [dead_band_zero_fraction:=0.5] [use_sim_time:=false]

Empty map_file / params_file mean the shipped config/valve_map.json and config/valve.yaml
(the paper's parameters). The node refuses to start on a map made for other parameters.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    args = [
        DeclareLaunchArgument('map_file', default_value='',
                              description='Static duty map (empty: the shipped one)'),
        DeclareLaunchArgument('params_file', default_value='',
                              description='Valve parameter YAML the map must match '
                                          '(empty: the paper\'s values)'),
        DeclareLaunchArgument('pwm_frequency_hz', default_value='50.0',
                              description='PWM frequency sent with every duty [Hz]'),
        DeclareLaunchArgument('supply_pressure_pa', default_value='400000.0',
                              description='Supply pressure until one is received, gauge [Pa]'),
        DeclareLaunchArgument('dead_band_zero_fraction', default_value='0.5',
                              description='Dead-band rule threshold [1]'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='Use /clock'),
    ]
    node = Node(
        package='valve_model_pkg', executable='flow_to_duty', name='flow_to_duty',
        output='screen', emulate_tty=True,
        parameters=[{
            'map_file': LaunchConfiguration('map_file'),
            'params_file': LaunchConfiguration('params_file'),
            'pwm_frequency_hz': LaunchConfiguration('pwm_frequency_hz'),
            'supply_pressure_pa': LaunchConfiguration('supply_pressure_pa'),
            'dead_band_zero_fraction': LaunchConfiguration('dead_band_zero_fraction'),
            'use_sim_time': LaunchConfiguration('use_sim_time'),
        }])
    return LaunchDescription(args + [node])
