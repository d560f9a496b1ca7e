# SPDX-License-Identifier: Apache-2.0
"""The one description of the graph (fiber_align.graph.description): pure, no ROS needed."""

from pathlib import Path
import subprocess
import sys

import pytest
import yaml

from fiber_align.graph import description as graph, registry
from fiber_align.graph.params import GraphError

ROOT = Path(__file__).resolve().parents[1]
CONTROL = ('simulated_actuator', 'hysteresis_compensator', 'fuzzy_pid_controller',
           'actuator_driver')


def setup_py_nodes():
    """Return the executables declared in setup.py's NODES list."""
    text = (ROOT / 'setup.py').read_text()
    start = text.index('NODES = [')
    block = text[start:text.index(']', start)]
    return [line.strip().strip("',") for line in block.splitlines()[1:] if line.strip()]


@pytest.mark.ros  # starts a process
def test_graph_module_imports_no_rclpy():
    code = ('import sys; import fiber_align.graph.description; '
            'sys.exit(1 if [m for m in sys.modules if m.startswith("rclpy")] else 0)')
    assert subprocess.run([sys.executable, '-c', code], timeout=60).returncode == 0


def test_default_graph_is_one_control_graph_process_plus_the_lifecycle_manager():
    assert graph.DEFAULT_COMPOSED is True       # measured: docs/ros_interface.md
    g = graph.build()
    assert g.composed
    assert [p.executable for p in g.processes] == ['control_graph', 'lifecycle_manager']
    assert g.processes[0].nodes == CONTROL
    assert g.nodes == CONTROL + ('lifecycle_manager',)


def test_multi_process_graph_is_one_process_per_node():
    g = graph.build(composed='false')
    assert [p.executable for p in g.processes] == list(CONTROL) + ['lifecycle_manager']
    for p in g.processes:
        assert p.nodes == (p.node_name,) and p.arguments == ()
    assert (g.sync_mode, g.controller, g.scenario, g.record) == (
        'realtime', 'composite', 'none', '')
    assert g.managed_nodes == ('actuator_driver',)
    assert g.node_params('lifecycle_manager')['node_names'] == ['actuator_driver']
    # every executable of this layout is a console script ros2 run can find
    assert set(p.executable for p in g.processes) <= set(setup_py_nodes())


def test_params_files_in_order_area_files_then_graph_file_then_the_users(tmp_path):
    user = tmp_path / 'mine.yaml'
    user.write_text(yaml.safe_dump({
        'actuator_driver': {'ros__parameters': {'v_max': 90}},
        '/**': {'ros__parameters': {'diagnostics_period_s': 1.0}}}))
    g = graph.build(params_file=str(user))
    names = [Path(f).name for f in g.params_files]
    expected = [Path(f).name for f in graph.AREA_FILES if Path(f).name in names]
    assert names == expected + ['fiber_align.yaml', 'mine.yaml']
    assert expected[:8] == ['plant.yaml', 'optics.yaml', 'controller.yaml',
                            'compensator.yaml', 'compensator_model.yaml', 'driver.yaml',
                            'sequencer.yaml', 'recorder.yaml']
    drv = g.node_params('actuator_driver')
    assert drv['v_max'] == 90.0 and drv['v_min'] == -20.0    # user file wins, key by key
    assert drv['diagnostics_period_s'] == 1.0
    # fiber_align.yaml's /** reaches every node; numeric lists become float lists
    assert g.node_params('simulated_actuator')['sync_mode'] == 'realtime'
    kd = g.node_params('fuzzy_pid_controller')['pid']['kd']
    assert all(isinstance(v, float) for v in kd)


def test_launch_arguments_override_the_files(tmp_path):
    model = tmp_path / 'model.yaml'
    model.write_text((ROOT / 'config' / 'hysteresis_paper.yaml').read_text())
    bag = tmp_path / 'bag'
    g = graph.build(sync_mode='lockstep', controller='pid', model_file=str(model),
                    record=str(bag))
    assert (g.sync_mode, g.controller, g.record) == ('lockstep', 'pid', str(bag))
    for node in CONTROL:
        assert g.node_params(node)['sync_mode'] == 'lockstep'
        assert g.node_params(node)['controller'] == 'pid'
    assert g.node_params('hysteresis_compensator')['model_file'] == str(model)
    assert g.node_params('bag_recorder')['output'] == str(bag)
    # composed (the default) the recorder is hosted beside the loop: no DDS between them
    assert g.processes[0].nodes[-1] == 'bag_recorder'
    assert g.node_params('simulated_actuator')['start_after_reader'] == ''
    apart = graph.build(record=str(bag), composed='false')
    assert apart.processes[-1].executable == 'bag_recorder'
    # multi-process the clock waits for the recorder's subscriptions
    assert apart.node_params('simulated_actuator')['start_after_reader'] == 'bag_recorder'
    assert not bag.exists()                     # describing the graph creates nothing


def test_a_recorded_scenario_ends_only_once_the_recorder_holds_it(tmp_path):
    recorded = graph.build(scenario='step', record=str(tmp_path / 'bag'))
    runner = recorded.node_params('scenario_runner')
    assert runner['exit_when_done'] and runner['wait_for_recorder']
    assert runner['recorder_wait_s'] > 0
    plain = graph.build(scenario='step').node_params('scenario_runner')
    assert plain['exit_when_done'] and not plain['wait_for_recorder']


@pytest.mark.parametrize('scenario, nodes', [
    ('none', CONTROL),
    ('sine', CONTROL + ('scenario_runner',)),
    ('align', CONTROL + ('alignment_sequencer',)),
    ('hysteresis-experiment', ('simulated_actuator', 'scenario_runner', 'actuator_driver')),
])
def test_scenario_decides_the_control_nodes(scenario, nodes):
    g = graph.build(scenario=scenario, composed='false')
    assert g.nodes[:len(nodes)] == nodes and g.scenario == scenario
    if scenario != 'none':
        assert g.node_params('scenario_runner')['scenario'] == scenario
    # the launch stops when the scenario runner's process exits, and only then
    assert [p.executable for p in g.processes if p.ends_graph] == (
        ['scenario_runner'] if 'scenario_runner' in nodes else [])


def test_composed_layout_is_one_control_graph_process(tmp_path):
    g = graph.build(composed='true', scenario='align', record=str(tmp_path / 'b'))
    first = g.processes[0]
    assert first.executable == 'control_graph' and first.node_name is None
    nodes = CONTROL + ('alignment_sequencer', 'bag_recorder')
    assert first.nodes == nodes
    assert first.argv('/p.yaml') == ['--nodes', ','.join(nodes), '--ros-args',
                                     '--params-file', '/p.yaml']
    assert [p.executable for p in g.processes[1:]] == ['lifecycle_manager']
    assert not any(p.ends_graph for p in g.processes)   # align runs until stopped
    assert g.managed_nodes == ('actuator_driver',)


def test_namespace_keys_the_node_sections_and_remaps_the_processes(tmp_path):
    user = tmp_path / 'ns.yaml'
    user.write_text(yaml.safe_dump({
        '/left/actuator_driver': {'ros__parameters': {'v_max': 80.0}},
        'fuzzy_pid_controller': {'ros__parameters': {'u_max': 50.0}}}))
    g = graph.build(namespace='/left/', params_file=str(user), composed='false')
    assert g.namespace == 'left'
    p = g.params()
    assert '/left/actuator_driver' in p and 'actuator_driver' not in p and '/**' in p
    assert p['/left/actuator_driver']['ros__parameters']['v_max'] == 80.0
    assert p['/left/fuzzy_pid_controller']['ros__parameters']['u_max'] == 50.0
    assert g.processes[0].ros_args('/p.yaml', g.namespace) == [
        '--ros-args', '--params-file', '/p.yaml', '-r', '__ns:=/left']
    assert g.processes[0].command('/p.yaml', g.namespace, (('a', 'b'),), 'py') == [
        'py', '-m', 'fiber_align.nodes.simulated_actuator', '--ros-args', '--params-file',
        '/p.yaml', '-r', '__ns:=/left', '-r', 'a:=b']
    out = g.write_params(str(tmp_path / 'params.yaml'))
    assert yaml.safe_load(Path(out).read_text()) == p


@pytest.mark.parametrize('kwargs, words', [
    ({'sync_mode': 'fast'}, ['sync_mode', 'realtime, lockstep']),
    ({'controller': 'lqr'}, ['controller', 'composite']),
    ({'scenario': 'walk'}, ['scenario', 'sine']),
    ({'composed': 'maybe'}, ['composed', 'true or false']),
    ({'namespace': 'bad name!'}, ['namespace', 'not a valid ROS namespace']),
    ({'namespace': '1left'}, ['namespace']),
    ({'params_file': '/nonexistent/p.yaml'}, ['params_file', 'does not exist']),
    ({'model_file': '/nonexistent/m.yaml'}, ['model_file', 'does not exist']),
])
def test_bad_arguments_get_one_clear_line(kwargs, words):
    with pytest.raises(GraphError) as err:
        graph.build(**kwargs)
    msg = str(err.value)
    assert '\n' not in msg
    for w in words:
        assert w in msg


def test_an_existing_record_directory_is_refused(tmp_path):
    with pytest.raises(GraphError, match='already exists'):
        graph.build(record=str(tmp_path))


def test_a_params_file_can_choose_the_scenario(tmp_path):
    user = tmp_path / 's.yaml'
    user.write_text(yaml.safe_dump({'scenario_runner': {'ros__parameters': {
        'scenario': 'step'}}}))
    assert graph.build(params_file=str(user)).scenario == 'step'
    assert graph.build(params_file=str(user), scenario='none').scenario == 'none'


def test_the_launch_file_takes_its_graph_from_graph_py():
    text = (ROOT / 'launch' / 'fiber_align.launch.py').read_text()
    assert 'g = describe(args)' in text and 'build' not in text
    for node in CONTROL + ('lifecycle_manager', 'bag_recorder'):
        assert "'%s'" % node not in text, 'node list written in the launch file: ' + node


def test_the_registry_is_the_one_list_of_nodes():
    """AREA_FILES and the hostable nodes come from the registry (graph.NODES)."""
    assert graph.AREA_FILES == tuple(f for n in (
        'simulated_actuator', 'fuzzy_pid_controller', 'hysteresis_compensator',
        'actuator_driver', 'alignment_sequencer', 'bag_recorder', 'scenario_runner',
        'lifecycle_manager') for f in graph.NODES[n].configs)
    assert set(registry.HOSTABLE) >= set(graph.control_nodes('align'))
    lifecycle = [n for n, s in graph.NODES.items() if s.lifecycle]
    assert lifecycle == ['actuator_driver', 'mdt693b_driver']
    for spec in graph.NODES.values():
        for f in spec.configs:
            assert (Path(graph.config_dir()) / f).is_file(), f


def test_dds_environment_keeps_the_users_ros_environment():
    env = graph.dds_environment({'ROS_DOMAIN_ID': '7'})
    assert 'ROS_AUTOMATIC_DISCOVERY_RANGE' not in env and env['ROS_DOMAIN_ID'] == '7'
    assert env['FASTRTPS_DEFAULT_PROFILES_FILE'].endswith('fastdds_profile.xml')
    mine = graph.dds_environment({'FASTRTPS_DEFAULT_PROFILES_FILE': '/x.xml',
                                  'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'})
    assert mine['FASTRTPS_DEFAULT_PROFILES_FILE'] == '/x.xml'
    assert mine['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SUBNET'


def test_the_graphs_participants_announce_themselves_every_second():
    """A new participant (each ``ros2`` command) finds them at their next announcement."""
    from xml.etree import ElementTree
    ns = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    path = graph.dds_environment({})['FASTRTPS_DEFAULT_PROFILES_FILE']
    lease = ElementTree.parse(path).find(
        'p:participant/p:rtps/p:builtin/p:discovery_config/p:leaseAnnouncement', ns)
    period_s = int(lease.findtext('p:sec', '0', ns)) + 1e-9 * int(
        lease.findtext('p:nanosec', '0', ns))
    assert 0.0 < period_s <= 1.0


@pytest.mark.parametrize('text, words', [
    ('actuator_driver:\n  ros__parameters:\n    v_maks: 80.0\n', "unknown parameter 'v_maks'"),
    ('no_node:\n  ros__parameters:\n    x: 1\n', 'unknown node'),
    ('actuator_driver:\n  ros__parameters:\n    v_max: fast\n', 'must be a number'),
])
def test_a_users_params_file_is_checked_against_the_shipped_files(tmp_path, text, words):
    """The one check of user names and kinds, for ros2 launch and bringup alike."""
    user = tmp_path / 'user.yaml'
    user.write_text(text)
    with pytest.raises(GraphError, match=words):
        graph.build(params_file=str(user))
    with pytest.raises(GraphError, match=words.split("'")[0]):
        graph.build(overrides={'actuator_driver': {'v_maks': 80.0}} if 'v_maks' in text
                    else {'no_node': {'x': 1}} if 'node' in words
                    else {'actuator_driver': {'v_max': 'fast'}})
