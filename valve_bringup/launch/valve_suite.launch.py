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
    clock          wall | lockstep   wall (default; hardware): every node on wall-clock
                   time, as before. lockstep: as `make demo` -- valve_lockstep_sim owns
                   /clock, steps valve model(s) and cylinder and waits for each control
                   tick's duty command; flow_to_duty and position_controller run with
                   use_sim_time and lockstep:=true. With backend:=can the emulator runs
                   with --clock sim on the loopback hub, the driver with use_sim_time, and
                   the simulation with valve_source:=external (one valve).
    cylinder       single | double   (lockstep) the double-acting example: valves cap/, rod/
    real_time_factor_max   (lockstep) pace cap; 0 = as fast as possible (default 1)

    ros2 launch valve_bringup valve_suite.launch.py clock:=lockstep cylinder:=double
"""
from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, ExecuteProcess, IncludeLaunchDescription,
                            OpaqueFunction)
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
        DeclareLaunchArgument('clock', default_value='wall', choices=['wall', 'lockstep'],
                              description='wall-clock nodes, or simulation time in lockstep '
                              '(as make demo)'),
        DeclareLaunchArgument('cylinder', default_value='single', choices=['single', 'double'],
                              description='(lockstep) single- or double-acting cylinder'),
        DeclareLaunchArgument('real_time_factor_max', default_value='1.0',
                              description='(lockstep) pace cap; 0 = as fast as possible'),
    ]
    wall = LaunchConfigurationEquals('clock', 'wall')

    simulator = Node(
        package='valve_model_pkg', executable='valve_simulator', name='valve_simulator',
        output='screen', condition=_both(LaunchConfigurationEquals('backend', 'sim'), wall),
        parameters=[{'params_file': params_file}])
    can_backend = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(PathJoinSubstitution(
            [FindPackageShare('valve_driver_pkg'), 'launch', 'can_backend.launch.py'])),
        launch_arguments={'params_file': params_file,
                          'interface': LaunchConfiguration('can_interface'),
                          'channel': LaunchConfiguration('can_channel')}.items(),
        condition=_both(LaunchConfigurationEquals('backend', 'can'), wall))
    flow_to_duty = Node(
        package='valve_model_pkg', executable='flow_to_duty', name='flow_to_duty',
        output='screen', parameters=[{'map_file': LaunchConfiguration('map_file')}],
        condition=wall)
    cylinder = Node(
        package='valve_model_pkg', executable='pneumatic_cylinder', name='pneumatic_cylinder',
        output='screen', condition=_both(IfCondition(LaunchConfiguration('pneumatics')), wall))
    controller = Node(
        package='valve_model_pkg', executable='position_controller',
        name='position_controller', output='screen',
        condition=_both(IfCondition(LaunchConfiguration('pneumatics')), wall))
    recorder = Node(
        package='valve_model_pkg', executable='valve_recorder', name='valve_recorder',
        output='screen', condition=IfCondition(LaunchConfiguration('record')),
        parameters=[{'output_dir': LaunchConfiguration('bag_dir')}])
    lockstep = OpaqueFunction(function=_lockstep_nodes,
                              condition=LaunchConfigurationEquals('clock', 'lockstep'))
    return LaunchDescription(args + [simulator, can_backend, flow_to_duty, cylinder,
                                     controller, recorder, lockstep])


def _both(a, b):
    """A condition that holds when both ``a`` and ``b`` hold."""
    from launch import Condition
    return Condition(predicate=lambda context: a.evaluate(context) and b.evaluate(context))


def _lockstep_nodes(context):
    """The processes of ``clock:=lockstep``, as valve_bringup.demo.suite_processes."""
    def arg(name: str) -> str:
        return LaunchConfiguration(name).perform(context)
    kind, backend = arg('cylinder'), arg('backend')
    if kind == 'double' and backend == 'can':
        raise RuntimeError('cylinder:=double needs backend:=sim (one valve on the CAN bus)')
    sim_time = {'use_sim_time': True, 'lockstep': True}
    actions = []
    sim_params = {'start_paused': False, 'cylinder': kind,
                  'real_time_factor_max': float(arg('real_time_factor_max')),
                  'params_file': arg('params_file')}
    if backend == 'can':
        channel = arg('can_channel')
        actions.append(ExecuteProcess(cmd=[
            'valve_controller_emulator', '--interface', arg('can_interface'), '--channel',
            channel, '--clock', 'sim'], output='screen', name='valve_controller_emulator'))
        actions.append(Node(
            package='valve_driver_pkg', executable='valve_can_driver',
            name='valve_can_driver', output='screen',
            parameters=[{'interface': arg('can_interface'), 'channel': channel,
                         'autostart': True, 'use_sim_time': True,
                         'telemetry_timeout_min_s': 5.0}]))
        sim_params['valve_source'] = 'external'
    actions.append(Node(package='valve_model_pkg', executable='valve_lockstep_sim',
                        name='valve_lockstep_sim', output='screen', parameters=[sim_params]))
    for ns in (('cap', 'rod') if kind == 'double' else ('',)):
        actions.append(Node(package='valve_model_pkg', executable='flow_to_duty',
                            name='flow_to_duty', namespace=ns or None, output='screen',
                            parameters=[{'map_file': arg('map_file'), **sim_time}]))
    actions.append(Node(package='valve_model_pkg', executable='position_controller',
                        name='position_controller', output='screen',
                        parameters=[{'cylinder': kind, **sim_time}]))
    return actions
