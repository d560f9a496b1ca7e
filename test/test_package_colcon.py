# SPDX-License-Identifier: Apache-2.0
"""
Check that the package installs the ament way.

``colcon build`` must put every executable where ``ros2 run fiber_align <exe>`` looks
and register the package in the ament index.
"""

import configparser
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def console_scripts():
    """Return the console_scripts names declared in setup.py."""
    text = (ROOT / 'setup.py').read_text()
    # the named entries ('fiber-align = ...', 'bringup = ...'), then the nodes' list
    names = re.findall(r"'([\w-]+) = fiber_align[\w.]*:main'", text)
    start = text.index('NODES = [')
    block = text[start:text.index(']', start)]
    names += [line.strip().strip("',") for line in block.splitlines()[1:] if line.strip()]
    return names


def test_setup_cfg_puts_scripts_in_lib_package():
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / 'setup.cfg')
    assert cfg['develop']['script_dir'] == '$base/lib/fiber_align'
    assert cfg['install']['install_scripts'] == '$base/lib/fiber_align'


@pytest.mark.ros
@pytest.mark.slow
def test_colcon_build_installs_every_executable(colcon_workspace):
    ws, proc = colcon_workspace      # conftest.py: one colcon build per session
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lib = ws / 'install' / 'fiber_align' / 'lib' / 'fiber_align'
    names = console_scripts()
    # fiber-align and the nodes of setup.py (bringup, control_graph, scenario_runner,
    # lifecycle_manager, power_meter among them)
    assert {'fiber-align', 'bringup', 'control_graph', 'scenario_runner',
            'lifecycle_manager', 'power_meter', 'simulated_actuator'} <= set(names)
    for name in names:
        exe = lib / name
        assert exe.is_file(), 'missing executable %s in %s' % (name, lib)
        assert exe.stat().st_mode & 0o111, '%s is not executable' % exe
    share = ws / 'install' / 'fiber_align' / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'fiber_align').is_file()
    assert (share / 'fiber_align' / 'package.xml').is_file()
    assert any((share / 'fiber_align' / 'config').glob('*.yaml'))
    assert (share / 'fiber_align' / 'launch' / 'fiber_align.launch.py').is_file()
    assert (share / 'fiber_align' / 'foxglove' / 'fiber_align.json').is_file()
