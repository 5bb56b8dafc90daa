from glob import glob

from setuptools import find_packages, setup

package_name = 'valve_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    # `colcon test` runs pytest in this directory (test/: the repository's tests of this
    # package, see README "Tests and packages").
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='valve suite team',
    maintainer_email='valve-suite@example.com',
    description='Starts the whole valve suite: demo, bench loop, supervisor, suite launch.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'valve_demo = valve_bringup.demo:main',
            'valve_bench_loop = valve_bringup.bench_loop:main',
        ],
    },
)
