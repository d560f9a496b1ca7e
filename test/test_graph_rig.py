# SPDX-License-Identifier: Apache-2.0
"""The two-axis rig's description (fiber_align.graph.rig): pure, no ROS needed."""

import subprocess
import sys

import pytest
import yaml

from fiber_align.graph import rig as graph_rig
from fiber_align.graph.params import GraphError
from fiber_align.simulation import alignment2d_scenarios as a2
from test_graph_description import CONTROL, setup_py_nodes


@pytest.mark.ros  # starts a process
def test_rig_module_imports_no_rclpy():
    code = ('import sys; import fiber_align.graph.rig; '
            'sys.exit(1 if [m for m in sys.modules if m.startswith("rclpy")] else 0)')
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0


def test_composed_rig_is_one_process_hosting_both_axes_and_the_rig_nodes():
    g = graph_rig.build_rig()
    assert [(p.name, p.executable, p.namespace) for p in g.processes] == [
        ('rig', 'control_graph', 'rig'), ('lifecycle_manager', 'lifecycle_manager', 'rig')]
    rig = g.processes[0]
    assert rig.nodes == tuple('%s/%s' % (a, n) for a in 'xy' for n in CONTROL) + (
        'simulated_optics_2d', 'alignment_sequencer_2d')
    assert rig.hosted('rig')[0] == ('simulated_actuator', '/rig/x')
    assert rig.hosted('rig')[-1] == ('alignment_sequencer_2d', '/rig')
    assert g.nodes[-3:] == ('simulated_optics_2d', 'alignment_sequencer_2d',
                            'lifecycle_manager')
    assert 'y/actuator_driver' in g.nodes
    argv = rig.command('/p.yaml', g.namespace)
    assert argv[-2:] == ['-r', '__ns:=/rig'] and '--params-file' in argv
    # the plant of each axis is the rig's (it publishes tip_position too)
    hosted = rig.arguments[1].split(',')
    assert rig.arguments[0] == '--nodes' and hosted[:4] == [
        'x/rig_actuator', 'x/hysteresis_compensator', 'x/fuzzy_pid_controller',
        'x/actuator_driver'] and hosted[-2:] == ['simulated_optics_2d',
                                                 'alignment_sequencer_2d']
    assert g.node_params('lifecycle_manager')['node_names'] == [
        'x/actuator_driver', 'y/actuator_driver']


def test_multi_process_rig_uses_console_scripts_and_a_namespace_per_axis():
    g = graph_rig.build_rig(composed='false', namespace='bench1')
    assert len(g.processes) == 2 * len(CONTROL) + 3
    assert set(p.executable for p in g.processes) <= set(setup_py_nodes())
    plants = [p for p in g.processes if p.node_name == 'simulated_actuator']
    assert [p.executable for p in plants] == ['simulated_actuator'] * 2
    assert {p.namespace for p in g.processes} == {'bench1', 'bench1/x', 'bench1/y'}
    assert 'x/actuator_driver' in g.nodes and 'y/simulated_actuator' in g.nodes


@pytest.mark.parametrize('seed', [0, 7])
def test_rig_takes_seeds_and_target_from_the_offline_description(seed):
    g = graph_rig.build_rig(seed=seed, sync_mode='lockstep')
    seeds = a2.run_seeds(seed)
    x, y = g.node_params('x/simulated_actuator'), g.node_params('y/simulated_actuator')
    assert (x['seed'], y['seed']) == (seeds['plant_x'], seeds['plant_y'])
    assert (x['publish_clock'], y['publish_clock']) == (True, False)
    assert x['tip_position_every'] == 1 and x['optical_power_every'] == 0
    o = g.node_params('simulated_optics_2d')
    assert o['seed'] == seeds['detector']
    assert (o['target']['position_x_m'], o['target']['position_y_m']) == \
        a2.random_target(seed)
    # one control rate for the plants, the optics and the sequencer; no stored period
    s = g.node_params('alignment_sequencer_2d')
    assert o['rate_hz'] == s['rate_hz'] == x['rate_hz'] == y['rate_hz']
    assert 'sample_period_s' not in o.get('optics', {}) and 'control_period_s' not in s
    assert g.sync_mode == 'lockstep' and x['sync_mode'] == 'lockstep'


def test_rig_params_file_is_plain_yaml_and_one_axis_can_differ(tmp_path):
    user = tmp_path / 'mine.yaml'
    user.write_text(yaml.safe_dump({
        'actuator_driver': {'ros__parameters': {'v_max': 90}},
        'y/actuator_driver': {'ros__parameters': {'v_max': 80}}}))
    g = graph_rig.build_rig(params_file=str(user))
    assert g.node_params('x/actuator_driver')['v_max'] == 90
    assert g.node_params('y/actuator_driver')['v_max'] == 80
    text = g.write_params(tmp_path / 'p.yaml').read_text()
    assert '&id' not in text and '*id' not in text     # no YAML aliases for rcl
    assert '/rig/x/fuzzy_pid_controller' in yaml.safe_load(text)


@pytest.mark.parametrize('kwargs', [dict(seed=-1), dict(seed='a'), dict(namespace='1rig'),
                                    dict(sync_mode='fast'), dict(params_file='/no/file')])
def test_bad_rig_arguments_are_refused_in_one_line(kwargs):
    with pytest.raises(GraphError):
        graph_rig.build_rig(**kwargs)


@pytest.mark.parametrize('option', [['--record', 'bag'], ['--no-noise'], ['--rate', '500'],
                                    ['-p', 'no-equals-sign']])
@pytest.mark.ros  # starts a process
def test_bringup_rig_refuses_one_axis_options_and_bad_params_in_one_line(option, tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'fiber_align.bringup', '--rig']
                          + option, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('bringup: error: '), proc.stderr
