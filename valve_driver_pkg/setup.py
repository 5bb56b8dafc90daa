from glob import glob

from setuptools import find_packages, setup

package_name = 'valve_driver_pkg'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'README.md']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    # The DBC files live beside protocol/codec.py, which finds them there.
    package_data={package_name: ['protocol/*.dbc', 'devices/data/*.eds', 'devices/data/*.yaml',
                                 'devices/data/examples/*']},
    install_requires=['setuptools'],
    # `colcon test` runs pytest in this directory (test/: the repository's tests of this
    # package, see README "Tests and packages").
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='valve suite team',
    maintainer_email='valve-suite@example.com',
    description='CAN driver and controller emulator for the valve suite.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'valve_can_driver = valve_driver_pkg.nodes.can_driver_node:main',
            'valve_controller_emulator = valve_driver_pkg.emulator.emulator_main:main',
            'valve_canopen_device = valve_driver_pkg.standins.canopen_device:main',
            'valve_j1939_device = valve_driver_pkg.standins.j1939_device:main',
            'valve_dbc_device = valve_driver_pkg.standins.dbc_device:main',
            'valve_can_replay = valve_driver_pkg.replay:main',
        ],
        # python-can finds the loopback bus by name: can.Bus(interface='tcp_loopback', ...)
        'can.interface': [
            'tcp_loopback = valve_driver_pkg.canbus.tcp_loopback:TcpLoopbackBus',
        ],
    },
)
