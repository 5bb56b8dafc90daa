from glob import glob

from setuptools import find_packages, setup

package_name = 'valve_model_pkg'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.json')),
        ('share/' + package_name + '/config/electronics', glob('config/electronics/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    # config/ is installed to share/ (above), where model.parameters looks for it; the
    # Python package itself carries no data files.
    install_requires=['setuptools'],
    # `colcon test` runs pytest in this directory (test/: the repository's tests of this
    # package, see README "Tests and packages").
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='valve suite team',
    maintainer_email='valve-suite@example.com',
    description='Nonlinear PWM solenoid valve model, simulator, static map, identification.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            # ROS 2 nodes
            'valve_simulator = valve_model_pkg.nodes.simulator_node:main',
            'valve_bank_simulator = valve_model_pkg.nodes.bank_simulator_node:main',
            'valve_lockstep_sim = valve_model_pkg.nodes.lockstep_sim_node:main',
            'flow_to_duty = valve_model_pkg.nodes.flow_to_duty_node:main',
            'pneumatic_cylinder = valve_model_pkg.nodes.cylinder_node:main',
            'position_controller = valve_model_pkg.nodes.position_controller_node:main',
            'valve_recorder = valve_model_pkg.nodes.recorder_node:main',
            # Offline commands (no ROS needed)
            'valve_simulate = valve_model_pkg.cli.simulate:main',
            'valve_map = valve_model_pkg.cli.map:main',
            'valve_flow_check = valve_model_pkg.cli.flow_check:main',
            'valve_identify = valve_model_pkg.cli.identify:main',
            'valve_import = valve_model_pkg.cli.import_record:main',
            'valve_identify_batch = valve_model_pkg.cli.identify_batch:main',
            'valve_report = valve_model_pkg.cli.report:main',
            # valve_demo and valve_bench_loop start the whole suite: package valve_bringup
        ],
    },
)
