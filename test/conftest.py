# SPDX-License-Identifier: Apache-2.0
"""Shared test set-up: every test process on its own ROS 2 domain; one colcon build."""

import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

# Discovery stays on this machine; no multicast leaves it.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
# Each pytest process gets a domain from its pid, so parallel runs (and helpers' runs)
# never see each other's nodes. Domains 1-100 are safe with Fast DDS port mapping.
if 'FIBER_ALIGN_TEST_KEEP_DOMAIN' not in os.environ:
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)


ROOT = Path(__file__).resolve().parents[1]
#: What a colcon source copy of the package leaves out (build products, venvs, runs).
COPY_IGNORE = shutil.ignore_patterns('.venv', '.git', 'build', 'install', 'log', '__pycache__',
                                     '*.egg-info', 'runs', 'out', '.pytest_cache')


@pytest.fixture(scope='session')
def colcon_workspace(tmp_path_factory):
    """
    Return ``(ws, proc)``: the package built once per session by ``colcon build``.

    ``ws`` is the workspace (``ws/install/fiber_align`` the install prefix), ``proc`` the
    finished ``colcon build`` (``returncode``, ``stdout``, ``stderr``). Shared by
    ``test_package_colcon.py`` and ``test_ros2_cli.py``.
    """
    colcon = Path(sys.executable).with_name('colcon')
    if not colcon.exists():
        pytest.fail('colcon is not installed in this environment (pip install colcon-core '
                    'colcon-ros, part of the test extras)')
    ws = tmp_path_factory.mktemp('colcon') / 'ws'
    shutil.copytree(ROOT, ws / 'src' / 'fiber_align', ignore=COPY_IGNORE)
    proc = subprocess.run([str(colcon), 'build', '--event-handlers', 'console_direct-'],
                          cwd=ws, capture_output=True, text=True, timeout=300)
    return ws, proc
