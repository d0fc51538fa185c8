"""ament_python package definition of seaforce_ros."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'seaforce_ros'

# Executables installed to lib/seaforce_ros so that `ros2 run seaforce_ros <name>` finds them.
CONSOLE_SCRIPTS = [
    'sim_node = seaforce_ros.nodes.sim_node:main',
    'controller_node = seaforce_ros.nodes.controller_node:main',
    'bringup = seaforce_ros.nodes.bringup:main',
    'hardware_node = seaforce_ros.nodes.hardware_node:main',
    'hardware_bringup = seaforce_ros.nodes.bringup:hardware_main',
    'bag_recorder = seaforce_ros.nodes.bag_recorder:main',
    'identify = seaforce_ros.tools.identify:main',
    'zwidth = seaforce_ros.tools.zwidth:main',
    'bag_reindex = seaforce_ros.tools.bag_reindex:main',
    'commission = seaforce_ros.tools.commission:main',
    'ethercat_scan = seaforce_ros.ethercat.scan:main',
    'first_power_on = seaforce_ros.ethercat.power_on:main',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml') + glob('config/*.json')
         + glob('config/*.xml')),
        ('share/' + PACKAGE + '/config/urdf', glob('config/urdf/*.xacro')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.xml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='seaforce_ros maintainers',
    maintainer_email='maintainers@seaforce-ros.org',
    description='DOB + endpoint friction feed-forward impedance control of a fluid-actuated '
                'series-elastic gripper, with simulation, EtherCAT I/O, recording and '
                'identification.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={'console_scripts': CONSOLE_SCRIPTS},
)
