# SPDX-License-Identifier: Apache-2.0
"""
Live parameters are checked for what they mean, not only for their type and range.

Through the nodes' own ``set_parameters`` (their on-set callbacks, as ``ros2 param set``
reaches them): feedback limits the setpoint range cannot work with, a zero gain rate and
a model file that is not there are refused with a reason that names the parameter and
the values allowed; turning the driver's watchdog off is accepted and is a WARN on
``/diagnostics``. Nodes are built in this process on their own rclpy context.
"""

import time

from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from fiber_align.config import ConfigError
from fiber_align.nodes.actuator_driver import ActuatorDriverNode
from fiber_align.nodes.fuzzy_pid_controller import FuzzyPidControllerNode
from fiber_align.nodes.hysteresis_compensator import HysteresisCompensatorNode
from fiber_align.nodes.ros.diagnostics import OK, WARN
from fiber_align.nodes.ros.qos import DIAG_QOS

pytestmark = pytest.mark.ros

NAMESPACE = 'parameter_meaning_test'


def make(ctx, cls, *overrides):
    """Build node ``cls`` in :data:`NAMESPACE` with ``-p`` ``overrides``."""
    context, nodes = ctx
    cli = ['--ros-args', '-r', '__ns:=/' + NAMESPACE]
    for o in overrides:
        cli += ['-p', o]
    node = cls(context=context, cli_args=cli)
    nodes.append(node)
    return node


def set_one(node, name, value):
    return node.set_parameters([Parameter(name, value=value)])[0]


def test_u_max_below_the_setpoint_voltage_is_refused(ctx):
    ctl = make(ctx, FuzzyPidControllerNode)
    res = set_one(ctl, 'u_max', -50.0)
    assert not res.successful
    assert res.reason.startswith('u_max=-50 V') and 'allowed: u_max > 0 V' in res.reason
    assert ctl.get_parameter('u_max').value == 100.0 and ctl.step.ctl.pid.u_max == 100.0
    res = set_one(ctl, 'u_min', 100.0)
    assert not res.successful and 'allowed: u_min < u_max' in res.reason
    assert set_one(ctl, 'u_max', 40.0).successful          # a narrower correction is fine
    assert ctl.step.ctl.pid.u_max == 40.0
    # a feedback law that drives alone must reach the top setpoint's voltage
    with pytest.raises(ConfigError, match=r'u_max=40 V is below the .* allowed: u_max >='):
        make(ctx, FuzzyPidControllerNode, 'controller:=fuzzy', 'u_max:=40.0')


def test_zero_gain_rate_is_refused_naming_the_parameter_and_its_range(ctx):
    ctl = make(ctx, FuzzyPidControllerNode)
    res = set_one(ctl, 'gain_rates_hz', [0.0])
    assert not res.successful
    assert 'gain_rates_hz' in res.reason and '[1, 1e+06]' in res.reason
    assert 'math domain' not in res.reason
    res = set_one(ctl, 'gain_rates_hz', [1000.0])
    assert not res.successful and 'one entry per rate of gain_rates_hz' in res.reason
    res = set_one(ctl, 'anti_windup', 'clamp')
    assert not res.successful and 'allowed: back-calculation' in res.reason
    res = set_one(ctl, 'fuzzy.output_scale', [0.8, 0.8])
    assert not res.successful and res.reason.startswith('fuzzy.output_scale has 2 entries')
    res = set_one(ctl, 'fuzzy.rules_dkp', ['PB'])
    assert not res.successful and res.reason.startswith('fuzzy.rules_dkp rejected: ')
    assert set_one(ctl, 'controller_state_every', 7).successful
    assert ctl.state_every == 7                             # in effect, not just stored


def test_missing_model_file_is_refused_at_set_and_at_start(ctx, tmp_path):
    comp = make(ctx, HysteresisCompensatorNode)
    res = set_one(comp, 'model_file', '/nonexistent.yaml')
    assert not res.successful
    assert res.reason.startswith("model_file='/nonexistent.yaml': no readable file")
    assert "allowed: ''" in res.reason
    assert comp.get_parameter('model_file').value == ''
    assert set_one(comp, 'model_file', 'hysteresis_paper.yaml').successful
    res = set_one(comp, 'weights_m_per_v', [-1.0] * len(comp.get_parameter(
        'thresholds_v').value))
    assert not res.successful and res.reason.startswith('weights_m_per_v=')
    with pytest.raises(ConfigError, match='model_file=.*no readable file'):
        make(ctx, HysteresisCompensatorNode, 'model_file:=%s' % (tmp_path / 'none.yaml'))


def test_watchdog_turned_off_at_run_time_is_a_warn_on_diagnostics(ctx):
    context, _ = ctx
    drv = make(ctx, ActuatorDriverNode, 'sync_mode:=realtime', 'diagnostics_period_s:=0.05')
    drv.trigger_configure()
    drv.trigger_activate()
    seen = []
    listener = make(ctx, lambda **kw: rclpy.create_node('listener', **kw))
    listener.create_subscription(
        DiagnosticArray, '/diagnostics', lambda m: seen.extend(
            (s.level[0], s.message) for s in m.status if s.name.endswith('actuator_driver')),
        DIAG_QOS)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(drv)
    ex.add_node(listener)

    def spin_until(cond, bound_s=5.0):
        end = time.monotonic() + bound_s
        while time.monotonic() < end and not cond():
            ex.spin_once(timeout_sec=0.02)
        return cond()

    try:
        assert spin_until(lambda: seen and seen[-1][0] == OK), seen[-3:]
        res = set_one(drv, 'watchdog_timeout_s', 0.0)
        assert res.successful                               # accepted: the user's call
        assert drv.s.driver.cores[''].timeout == 0.0
        del seen[:]
        assert spin_until(lambda: any(lv == WARN for lv, _ in seen)), seen[-3:]
        msg = [m for lv, m in seen if lv == WARN][-1]
        assert 'protection off: watchdog_timeout_s=0.0: the watchdog is off' in msg
        assert set_one(drv, 'watchdog_timeout_s', 0.05).successful
        del seen[:]
        assert spin_until(lambda: len(seen) > 2 and seen[-1][0] == OK), seen[-3:]
    finally:
        ex.shutdown()
