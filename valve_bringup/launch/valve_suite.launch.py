"""Launch the whole suite: valve backend, flow_to_duty, cylinder plant, controller, recorder.

    ros2 launch valve_bringup valve_suite.launch.py                 # simulator backend
    ros2 launch valve_bringup valve_suite.launch.py backend:=can    # CAN driver + emulator
    ros2 launch valve_bringup valve_suite.launch.py record:=true bag_dir:=/bags

Arguments:
    backend        sim | can   which node provides valve/state (same topic, same type)
    params_file    valve parameter YAML for the simulator / emulator (empty: the paper's)
    map_file       static duty map for flow_to_duty (empty: the shipped one)
    pneumatics     true | false   start the cylinder plant and the position controller
    record         true | false   start valve_recorder
    bag_dir        where valve_recorder writes its bags
    can_interface, can_channel    python-can bus of the CAN backend (default: the loopback
                   hub the emulator serves; socketcan/can0 for hardware)
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.conditions import IfCondition, LaunchConfigurationEquals
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    params_file = LaunchConfiguration('params_file')
    args = [
        DeclareLaunchArgument('backend', default_value='sim', choices=['sim', 'can'],
                              description='valve/state from the simulator or the CAN driver'),
        DeclareLaunchArgument('params_file', default_value='',
                              description='Valve parameter YAML (empty: the paper\'s values)'),
        DeclareLaunchArgument('map_file', default_value='',
                              description='Static duty map for flow_to_duty (empty: shipped)'),
        DeclareLaunchArgument('pneumatics', default_value='true',
                              description='Start the cylinder plant and position controller'),
        DeclareLaunchArgument('record', default_value='false',
                              description='Record the suite\'s topics with valve_recorder'),
        DeclareLaunchArgument('bag_dir', default_value='bags',
                              description='Directory for the recorded bags'),
        DeclareLaunchArgument('can_interface', default_value='tcp_loopback',
                              description='python-can interface of the CAN backend'),
        DeclareLaunchArgument('can_channel', default_value='127.0.0.1:29536',
                              description='python-can channel of the CAN backend'),
    ]

    simulator = Node(
        package='valve_model_pkg', executable='valve_simulator', name='valve_simulator',
        output='screen', condition=LaunchConfigurationEquals('backend', 'sim'),
        parameters=[{'params_file': params_file}])
    can_backend = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(PathJoinSubstitution(
            [FindPackageShare('valve_driver_pkg'), 'launch', 'can_backend.launch.py'])),
        launch_arguments={'params_file': params_file,
                          'interface': LaunchConfiguration('can_interface'),
                          'channel': LaunchConfiguration('can_channel')}.items(),
        condition=LaunchConfigurationEquals('backend', 'can'))
    flow_to_duty = Node(
        package='valve_model_pkg', executable='flow_to_duty', name='flow_to_duty',
        output='screen', parameters=[{'map_file': LaunchConfiguration('map_file')}])
    cylinder = Node(
        package='valve_model_pkg', executable='pneumatic_cylinder', name='pneumatic_cylinder',
        output='screen', condition=IfCondition(LaunchConfiguration('pneumatics')))
    controller = Node(
        package='valve_model_pkg', executable='position_controller',
        name='position_controller', output='screen',
        condition=IfCondition(LaunchConfiguration('pneumatics')))
    recorder = Node(
        package='valve_model_pkg', executable='valve_recorder', name='valve_recorder',
        output='screen', condition=IfCondition(LaunchConfiguration('record')),
        parameters=[{'output_dir': LaunchConfiguration('bag_dir')}])
    return LaunchDescription(args + [simulator, can_backend, flow_to_duty, cylinder,
                                     controller, recorder])
