# SPDX-License-Identifier: Apache-2.0
"""The sensorless hardware graph (processes of ``build_hardware``) on the emulators."""

from fiber_align.nodes.bringup.hardware import graph_trial


def test_sensorless_graph_aligns_on_the_emulators():
    r = graph_trial(seed=5, slot_m=41e-6)
    assert r['aligned'], r['status']
    assert r['align_wall_s'] <= 3.0, r
    assert r['final_loss_db'] < 0.1, r
    lo, hi = r['v_range']
    assert 0.0 <= lo and hi <= 100.0 and r['commands'] > 50
    assert all(code == 0 for code in r['exit_codes'].values()), r['exit_codes']


def test_hardware_graph_description(tmp_path):
    from pathlib import Path

    import pytest
    import yaml

    from fiber_align.nodes import graph
    from fiber_align.nodes.graph_hardware import build_hardware
    g = build_hardware(port='/dev/ttyUSB7', visa_resource='TCPIP::h::1::SOCKET',
                       composed='false', record=str(tmp_path / 'bag'))
    assert [p.name for p in g.processes] == [
        'alignment_sequencer', 'hysteresis_compensator', 'actuator_driver', 'power_meter',
        'lifecycle_manager', 'bag_recorder']
    names = [Path(f).name for f in g.params_files]
    assert names[-3:] == ['fiber_align.yaml', 'hardware.yaml', 'sequencer_hardware.yaml']
    drv = g.node_params('actuator_driver')
    assert (drv['backend'], drv['port'], drv['sensorless'], drv['v_min']) == (
        'mdt693b', '/dev/ttyUSB7', True, 0.0)
    assert g.node_params('power_meter')['resource'] == 'TCPIP::h::1::SOCKET'
    assert g.node_params('alignment_sequencer')['control_period_s'] == 0.01
    assert g.node_params('lifecycle_manager')['managed_nodes'] == ['actuator_driver']
    assert g.controller == 'feedforward' and g.managed_nodes == ('actuator_driver',)
    assert 'simulated_actuator' not in g.nodes and 'fuzzy_pid_controller' not in g.nodes
    # the simulated graph is untouched: no hardware file, the topic backend
    sim = graph.build()
    assert sim.node_params('actuator_driver')['backend'] == 'topic'
    assert not sim.node_params('actuator_driver')['sensorless']
    # a params file that turns the backend back to topic is refused, in one line
    user = tmp_path / 'u.yaml'
    user.write_text(yaml.safe_dump({'actuator_driver': {'ros__parameters': {
        'backend': 'topic'}}}))
    with pytest.raises(graph.GraphError, match='backend mdt693b'):
        build_hardware(params_file=str(user))
