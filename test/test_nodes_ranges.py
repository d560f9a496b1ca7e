# SPDX-License-Identifier: Apache-2.0
"""
Every range a node declares is the row the graph checks params files against (issue 39.6).

Each node of every graph is built in this process from the params file its graph writes
(its namespace, its node name) and every number parameter it declared is compared with
:func:`fiber_align.graph.ranges.range_of`: the same low and high, or no range on either
side. So ``ros2 launch ... params_file:=`` and ``bringup --params-file`` refuse before
any process starts exactly the values a node would refuse when it starts. The power
meter and the live view declare their own table of ``graph/ranges.py`` as it is (they
open a device or a server when built).
"""

import math

import pytest

from fiber_align.graph import ranges
from fiber_align.graph.arguments import describe
from fiber_align.graph.refusals import core_keys
from fiber_align.nodes import live_view, power_meter
from fiber_align.nodes.actuator_driver import ActuatorDriverNode
from fiber_align.nodes.alignment_sequencer import (AlignmentSequencerNode, RigSequencerNode,
                                                   StationSequencerNode)
from fiber_align.nodes.bag_recorder import BagRecorder
from fiber_align.nodes.fuzzy_pid_controller import FuzzyPidControllerNode
from fiber_align.nodes.hysteresis_compensator import HysteresisCompensatorNode
from fiber_align.nodes.lifecycle_manager import LifecycleManager
from fiber_align.nodes.scenario_runner import ScenarioRunnerNode
from fiber_align.nodes.simulated_actuator import SimulatedActuatorNode
from fiber_align.nodes.simulated_optics import SimulatedOpticsNode, StationOpticsNode

pytestmark = pytest.mark.ros

#: (graph arguments, namespace of the node, node base name, how to build it)
CASES = [
    ({'scenario': 'align', 'record': '{tmp}/bag'}, '', 'simulated_actuator',
     SimulatedActuatorNode),
    ({'scenario': 'align'}, '', 'hysteresis_compensator', HysteresisCompensatorNode),
    ({'scenario': 'align'}, '', 'fuzzy_pid_controller', FuzzyPidControllerNode),
    ({'scenario': 'align'}, '', 'actuator_driver', ActuatorDriverNode),
    ({'scenario': 'align'}, '', 'alignment_sequencer', AlignmentSequencerNode),
    ({'scenario': 'sine'}, '', 'scenario_runner', ScenarioRunnerNode),
    ({'scenario': 'sine'}, '', 'lifecycle_manager', LifecycleManager),
    ({'scenario': 'sine', 'record': '{tmp}/bag'}, '', 'bag_recorder', BagRecorder),
    ({'rig': 'true'}, 'rig', 'simulated_optics_2d', SimulatedOpticsNode),
    ({'rig': 'true'}, 'rig', 'alignment_sequencer_2d', RigSequencerNode),
    ({'station': 'true'}, 'station', 'simulated_station_optics', StationOpticsNode),
    ({'station': 'true'}, 'station', 'station_sequencer', StationSequencerNode),
    ({'hardware': 'true'}, '', 'actuator_driver', ActuatorDriverNode),
    ({'rig': 'true', 'hardware': 'true'}, 'rig', 'mdt693b_driver',
     lambda **kw: ActuatorDriverNode(node_name='mdt693b_driver', **kw)),
]


def _declared(node, name):
    """Return ``(low, high)`` of the range ``name`` was declared with, or None."""
    d = node.describe_parameters([name])[0]
    r = list(d.floating_point_range) or list(d.integer_range)
    return (r[0].from_value, r[0].to_value) if r else None


@pytest.mark.parametrize('args, ns, base, build', CASES,
                         ids=['%s-%s' % (ns or '1d', b) for _, ns, b, _ in CASES])
def test_a_node_declares_the_ranges_the_graph_checks(ctx, tmp_path, args, ns, base, build):
    args = {k: v.replace('{tmp}', str(tmp_path)) for k, v in args.items()}
    g = describe(args)
    path = g.write_params(str(tmp_path / 'params.yaml'))
    context, nodes = ctx
    cli = ['--ros-args', '--params-file', path] + (['-r', '__ns:=/' + ns] if ns else [])
    node = build(context=context, cli_args=cli)
    nodes.append(node)
    machine = node.get_parameter('machine').value if node.has_parameter('machine') else None
    checked = 0
    for name, param in sorted(node._parameters.items()):
        value = param.value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            continue                    # lists: checked by the node's own check at start
        p = {'machine': machine, name: value}
        row = ranges.range_of(base, name, p, core_keys(base, p))
        want = None if row is None else (row[1], row[2])
        got = _declared(node, name)
        assert (got is None) == (want is None), (base, name, got, want)
        if got is not None:
            assert all(math.isclose(a, b, rel_tol=1e-12) for a, b in zip(got, want)), \
                (base, name, got, want)
            checked += 1
    assert checked >= 1, base


def test_the_meter_and_the_view_declare_their_tables_of_graph_ranges():
    assert power_meter.PARAMS is ranges.POWER_METER_RANGES
    assert live_view.PARAMS is ranges.LIVE_VIEW_RANGES
