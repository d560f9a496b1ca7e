# SPDX-License-Identifier: Apache-2.0
"""
Parameters are the only truth of a node (issue 11).

For each node: a ``-p`` override and a params-file override of a key of each core object
reach that object (seen in the object the node built), a wrong type or an out-of-range
value is refused with the reason, and values two nodes share (the shaping of the
composite loop, the rate) stay one value for both whatever node an override names.
Nodes are built in this process on their own rclpy context (no graph, no spinning).
"""

import time

import pytest
import rclpy
from rclpy.exceptions import InvalidParameterValueException, ParameterException
from rclpy.parameter import Parameter
import yaml

from fiber_align.config import ConfigError
from fiber_align.graph import description as graph
from fiber_align.nodes.actuator_driver import ActuatorDriverNode
from fiber_align.nodes.alignment_sequencer import AlignmentSequencerNode
from fiber_align.nodes.bag_recorder import BagRecorder
from fiber_align.nodes.fuzzy_pid_controller import FuzzyPidControllerNode
from fiber_align.nodes.hysteresis_compensator import HysteresisCompensatorNode
from fiber_align.nodes.lifecycle_manager import LifecycleManager
from fiber_align.nodes.scenario_runner import ScenarioRunnerNode
from fiber_align.nodes.simulated_actuator import SimulatedActuatorNode

pytestmark = pytest.mark.ros

#: What a node refuses at start-up: rclpy's range/type checks, or the node's own.
REFUSED = (InvalidParameterValueException, ParameterException, ConfigError, ValueError,
           TypeError)


#: DiagnosticStatus WARN (the message field is a byte).
WARN_LEVEL = b'\x01'

#: Namespace of the nodes built here.
NAMESPACE = 'parameters_test'


def make(ctx, cls, *overrides, params_file=None):
    """Build node ``cls`` with ``-p`` ``overrides`` (``name:=value``) and a params file."""
    context, nodes = ctx
    # a namespace of their own: no later test of this process may meet their services
    # in the discovery cache (a ghost actuator_driver/change_state answers nothing)
    cli = ['--ros-args', '-r', '__ns:=/' + NAMESPACE]
    if params_file:
        cli += ['--params-file', str(params_file)]
    for o in overrides:
        cli += ['-p', o]
    node = cls(context=context, cli_args=cli)
    nodes.append(node)
    return node


def params_file(tmp_path, sections, name='user.yaml'):
    """Write ``{node: {param: value}}`` as a ROS params file; return its path."""
    path = tmp_path / name
    path.write_text(yaml.safe_dump({'/%s/%s' % (NAMESPACE, n) if n != '/**' else n:
                                    {'ros__parameters': p} for n, p in sections.items()}))
    return path


def graph_params(tmp_path, sections):
    """Return the graph's merged params file for a user file with ``sections``."""
    g = graph.build(namespace=NAMESPACE, params_file=str(params_file(tmp_path, sections)))
    return g.write_params(str(tmp_path / 'graph.yaml'))


def taps(shaper):
    return list(shaper.taps)


def test_compensator_builds_from_its_parameters(ctx, tmp_path):
    base = make(ctx, HysteresisCompensatorNode).step.ff
    assert base.lead is not None and base.shaper is not None
    ff = make(ctx, HysteresisCompensatorNode, 'delay_compensation:=false',
              'shaping_damping_ratio:=0.2').step.ff
    assert ff.lead is None, '-p delay_compensation:=false reaches the feedforward'
    assert taps(ff.shaper) != pytest.approx(taps(base.shaper)), '-p shaping reaches it'
    w = [float(x) * 2 for x in base.model.weights]
    pf = params_file(tmp_path, {'hysteresis_compensator': {
        'weights_m_per_v': w, 'shaping': 'none'}})
    ff = make(ctx, HysteresisCompensatorNode, params_file=pf).step.ff
    assert list(ff.model.weights) == pytest.approx(w)
    assert ff.shaper is None


def test_controller_builds_from_its_parameters(ctx, tmp_path):
    base = make(ctx, FuzzyPidControllerNode).step.ctl
    ctl = make(ctx, FuzzyPidControllerNode, 'u_max:=40.0', 'shaping:=zvd').step.ctl
    assert ctl.pid.u_max == 40.0
    assert len(taps(ctl.reference_filter.shaper)) > len(taps(base.reference_filter.shaper))
    pf = params_file(tmp_path, {'fuzzy_pid_controller': {'u_min': -30.0,
                                                         'composite_feedback_reference':
                                                         'raw'}})
    ctl = make(ctx, FuzzyPidControllerNode, params_file=pf).step.ctl
    assert ctl.pid.u_min == -30.0 and ctl.reference_filter is None


def test_plant_builds_from_its_parameters(ctx, tmp_path):
    node = make(ctx, SimulatedActuatorNode, 'damping_ratio:=0.05', 'optics.gap_m:=2.0e-5')
    assert node.plant.damping_ratio == 0.05
    assert node.optics.coupling.gap_m == 2.0e-5
    pf = params_file(tmp_path, {'simulated_actuator': {'v_max': 80.0, 'optics': {
        'rin_db': 0.0}}})
    node = make(ctx, SimulatedActuatorNode, params_file=pf)
    assert node.plant.v_max == 80.0
    assert node.optics.detector.rin_db == 0.0


def configured(node):
    """Return the driver ``node`` after its configure transition (it builds its core)."""
    node.trigger_configure()
    return node


def test_driver_builds_from_its_parameters(ctx, tmp_path):
    drv = configured(make(ctx, ActuatorDriverNode, 'v_max:=80.0', 'latch_trips:=5'))
    core = drv.s.driver.cores['']
    assert core.v_max == 80.0 and core.latch_trips == 5
    pf = params_file(tmp_path, {'actuator_driver': {'watchdog_timeout_s': 0.02}})
    drv = configured(make(ctx, ActuatorDriverNode, params_file=pf))
    assert drv.s.driver.cores[''].timeout == 0.02


def test_sequencer_builds_from_its_parameters(ctx, tmp_path):
    node = make(ctx, AlignmentSequencerNode, 'threshold_sigma:=7.0')
    assert node.get_parameter('threshold_sigma').value == 7.0
    assert node.seq.p['threshold_sigma'] == 7.0
    pf = params_file(tmp_path, {'alignment_sequencer': {'range_max_m': 50.0e-6}})
    assert make(ctx, AlignmentSequencerNode, params_file=pf).seq.p['range_max_m'] == 50.0e-6
    with pytest.raises(REFUSED):            # the unit's range: 1 m is no fiber offset
        make(ctx, AlignmentSequencerNode, 'range_max_m:=1.0')


def test_scenario_runner_builds_from_its_parameters(ctx, tmp_path):
    node = make(ctx, ScenarioRunnerNode, 'scenario:=sine', 'duration_s:=0.25')
    assert node.name_ == 'sine' and node.duration_s == 0.25
    pf = params_file(tmp_path, {'scenario_runner': {'scenario': 'step',
                                                    'setpoint_max_m': 30.0e-6}})
    node = make(ctx, ScenarioRunnerNode, params_file=pf)
    assert node.name_ == 'step' and node.source.hi == 30.0e-6
    with pytest.raises(REFUSED):
        make(ctx, ScenarioRunnerNode, 'scenario:=zigzag')


def test_lifecycle_manager_and_recorder_build_from_their_parameters(ctx, tmp_path):
    node = make(ctx, LifecycleManager, 'node_names:=[a, b]', 'autostart:=false')
    assert node.managed == ['a', 'b']
    bag = tmp_path / 'bag'
    pf = params_file(tmp_path, {'bag_recorder': {'output': str(bag), 'queue_depth': 123}})
    rec = make(ctx, BagRecorder, params_file=pf)
    assert rec.output == str(bag) and rec.depth == 123
    rec.close()
    with pytest.raises(REFUSED):
        make(ctx, BagRecorder, 'queue_depth:=0', 'output:=%s' % (tmp_path / 'bag2'))


def test_lifecycle_manager_takes_the_old_name_managed_nodes_with_one_warn(ctx, capfd):
    node = make(ctx, LifecycleManager, 'autostart:=false')
    assert node.managed == ['actuator_driver'], 'node_names from config/'
    assert 'deprecated' not in capfd.readouterr().err
    node = make(ctx, LifecycleManager, 'managed_nodes:=[c]', 'node_names:=[a, b]',
                'autostart:=false')
    assert node.managed == ['c'], 'the old name, set, wins'
    err = capfd.readouterr().err
    assert err.count('managed_nodes is deprecated: use node_names') == 1, err


@pytest.mark.parametrize('cls,override,why', [
    (ActuatorDriverNode, 'v_max:=1000.0', 'range'),
    (ActuatorDriverNode, 'v_max:=fast', 'type'),
    (SimulatedActuatorNode, 'damping_ratio:=-1.0', 'range'),
    (SimulatedActuatorNode, 'rate_hz:=fast', 'type'),
    (FuzzyPidControllerNode, 'controller:=bang-bang', 'choice'),
    (HysteresisCompensatorNode, 'shaping_damping_ratio:=2.0', 'range'),
])
def test_bad_start_values_are_refused(ctx, cls, override, why):
    with pytest.raises(REFUSED) as info:
        make(ctx, cls, override)
    assert str(info.value), 'the refusal says why (%s)' % why


def test_bad_live_values_are_refused_with_the_reason(ctx):
    drv = configured(make(ctx, ActuatorDriverNode))
    res = drv.set_parameters([Parameter('v_max', value=1000.0)])[0]
    assert not res.successful and res.reason
    assert drv.s.driver.cores[''].v_max != 1000.0
    ctl = make(ctx, FuzzyPidControllerNode)
    res = ctl.set_parameters([Parameter('u_max', value='high')])[0]
    assert not res.successful and res.reason
    res = ctl.set_parameters([Parameter('ki', value=-1.0)])[0] if ctl.has_parameter('ki') \
        else ctl.set_parameters([Parameter('pid.ki', value=[-1.0, -1.0])])[0]
    assert not res.successful and 'range' in res.reason


def test_a_refused_change_is_logged_and_reported_on_diagnostics(ctx):
    """``ros2 param set``'s path (set_parameters_atomically) and in-process set_parameters."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    context, _ = ctx
    drv = configured(make(ctx, ActuatorDriverNode))
    seen = []
    watcher = rclpy.create_node('refusal_watcher', context=context)
    watcher.create_subscription(DiagnosticArray, '/diagnostics', lambda m: seen.extend(
        (s.level, s.message) for s in m.status if s.name.endswith('actuator_driver')), 50)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(watcher)
    try:
        ex.spin_once(timeout_sec=0.5)       # the reader matched before the refusals
        res = drv.set_parameters_atomically([Parameter('v_max', value=1000.0)])
        assert not res.successful
        res = drv.set_parameters([Parameter('safe_voltage_v', value=-200.0)])[0]
        assert not res.successful
        end = time.monotonic() + 10.0
        words = ('parameter change refused: v_max', 'parameter change refused: '
                 'safe_voltage_v')
        while time.monotonic() < end and not all(
                any(lv == WARN_LEVEL and w in m for lv, m in seen) for w in words):
            ex.spin_once(timeout_sec=0.1)
    finally:
        ex.shutdown()
        watcher.destroy_node()
    for w in words:
        assert any(lv == WARN_LEVEL and w in m for lv, m in seen), (w, seen[-5:])


def test_shared_shaping_is_one_value_for_compensator_and_controller(ctx, tmp_path):
    """The defect: an override of one node's shaping split the composite loop's halves."""
    default = taps(make(ctx, HysteresisCompensatorNode).step.ff.shaper)
    for node in ('hysteresis_compensator', 'fuzzy_pid_controller', '/**'):
        pf = graph_params(tmp_path, {node: {'shaping_damping_ratio': 0.2}})
        comp = make(ctx, HysteresisCompensatorNode, params_file=pf).step.ff.shaper
        ctl = make(ctx, FuzzyPidControllerNode, params_file=pf).step.ctl.reference_filter.shaper
        assert taps(comp) == pytest.approx(taps(ctl)), node
        assert taps(comp) != pytest.approx(default), node


def test_shared_rate_is_one_value_for_the_loop(ctx, tmp_path):
    """``rate_hz`` set for the plant only is the rate of every loop node."""
    pf = graph_params(tmp_path, {'simulated_actuator': {'rate_hz': 2000.0}})
    for cls in (SimulatedActuatorNode, HysteresisCompensatorNode, FuzzyPidControllerNode,
                ActuatorDriverNode):
        assert make(ctx, cls, params_file=pf).get_parameter('rate_hz').value == 2000.0


def test_shared_value_set_twice_differently_is_refused(tmp_path):
    with pytest.raises(graph.GraphError, match='shaping_damping_ratio'):
        graph.build(namespace=NAMESPACE, params_file=str(params_file(tmp_path, {
            'hysteresis_compensator': {'shaping_damping_ratio': 0.1},
            'fuzzy_pid_controller': {'shaping_damping_ratio': 0.2}})))
