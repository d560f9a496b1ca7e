# SPDX-License-Identifier: Apache-2.0
"""control_graph's command line: hosted nodes, their sub-namespaces, its ROS arguments."""

import pytest

from fiber_align.nodes import control_graph


def test_control_graph_orders_sub_namespaces_and_strips_the_process_namespace():
    names = control_graph.parse_nodes(
        ['--nodes', 'x/actuator_driver,x/rig_actuator,simulated_optics_2d,y/rig_actuator'])
    assert names == ['x/rig_actuator', 'x/actuator_driver', 'simulated_optics_2d',
                     'y/rig_actuator']
    ns, ros = control_graph.ros_arguments(
        ['control_graph', '--nodes', 'a', '--ros-args', '--params-file', 'p.yaml', '-r',
         '__ns:=/rig', '-p', 'rate_hz:=500.0'])
    assert ns == '/rig' and ros == ['--params-file', 'p.yaml', '-p', 'rate_hz:=500.0']
    with pytest.raises(SystemExit):
        control_graph.parse_nodes(['--nodes', 'x/no_such_node'])
    with pytest.raises(SystemExit):
        control_graph.parse_nodes(['--nodes', 'x/rig_actuator,x/rig_actuator'])
