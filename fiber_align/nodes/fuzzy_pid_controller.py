# SPDX-License-Identifier: Apache-2.0
"""
``fuzzy_pid_controller``: the feedback law of the control core as a ROS 2 node.

Runs once per ``displacement`` sample (sensor_msgs/JointState, m): ``fb_k =
controller.step(r_k, y_k)`` with the law :func:`fiber_align.control.factory.
build_controller` builds for the graph's ``controller``, exactly what the offline loop
computes. ``r`` is ``reference`` (std_msgs/Float64, m): the setpoint the compensator
accepted, latched. Publishes ``feedback_voltage`` (V) and ``controller_state``
(Float64MultiArray, labelled dims in SI; every ``controller_state_every`` samples).
``~/reset`` (std_srvs/Trigger) clears the integral and filters. Lockstep pairs the i-th
displacement with the i-th reference; realtime follows the rules of
:class:`fiber_align.control.realtime.ControllerStep` (parked while the drive is held,
output held while it is stale, bumpless resumes). The parameters of
``config/controller.yaml`` change live (checked, state kept); the graph-wide values are
read-only. The full behaviour: docs/ros_interface.md, section "fuzzy_pid_controller".
"""

import math
import sys

from rclpy.node import Node
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension
from std_srvs.srv import Trigger

from fiber_align.config import ConfigError, flatten, unflatten
from fiber_align.control.factory import build_controller, PARAM_RANGES
from fiber_align.control.fuzzy_pid import carry_state
from fiber_align.control.realtime import ControllerStep, extend_lead
from fiber_align.control.trajectory import stamp_ns
from fiber_align.graph import checks
from fiber_align.graph.params import SHARED
from fiber_align.graph.ranges import CONTROLLER_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.bus import Pub, subscription
from fiber_align.nodes.ros.diagnostics import OK
from fiber_align.nodes.ros.loop_io import GRAPH, LoopIO
from fiber_align.nodes.ros.params import declare, declare_row, node_defaults
from fiber_align.nodes.ros.qos import LOCKSTEP_QOS, REFERENCE_LATCHED_QOS
from fiber_align.nodes.ros.qos import sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['fuzzy_pid_controller']
STATE_LABELS = ('error_m', 'error_rate_m_per_s', 'kp_v_per_m', 'ki_v_per_m_s',
                'kd_v_s_per_m', 'output_v')


class FuzzyPidControllerNode(Node):
    """Transport and parameters around the fuzzy PID of the control core."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare parameters (defaults from config/), build the controller, wire topics.

        :param bus: the :class:`~fiber_align.nodes.ros.bus.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        io = self.io = LoopIO(self, d, bus)     # graph values, shaping, setpoint, health
        g, self.shaping = io.g, io.shaping
        self.mode, self.rate_hz, self.lockstep = g['controller'], io.rate_hz, io.lockstep
        self.sp = io.sp
        self.state_every = declare_row(self, d, CONTROLLER_RANGES, 'controller_state_every',
                                       False)
        own = GRAPH + ('controller_state_every',)
        core = {k: v for k, v in d.items() if k not in own and k not in SHARED}
        self.core_names = []
        for name, value in flatten(core).items():
            lo, hi = PARAM_RANGES.get(name.split('.')[-1], (None, None))
            scalar = isinstance(value, (int, float)) and not isinstance(value, bool)
            declare(self, {name: value}, name, 'controller parameter (SI, see '
                    'controller.yaml)', lo if scalar else None, hi if scalar else None)
            self.core_names.append(name)
        # what the limits must reach: the setpoint range at the design gain (m, m/V)
        self.limits_for = (self.mode, g['setpoint_min_m'], g['setpoint_max_m'], io.design[1])
        why = self._check({n: self.get_parameter(n).value for n in self.core_names},
                          self._core_params())
        if why:
            raise ConfigError('fuzzy_pid_controller: %s' % why)
        self.step = ControllerStep(None, *io.step_args())
        self.step.ctl = self._make(self._core_params())
        self.add_on_set_parameters_callback(self._on_set)

        pub_qos = sample_pub_qos(self.lockstep)
        self.pub_fb = Pub(self, Float64, 'feedback_voltage', pub_qos, bus, slack=io.slack)
        self.pub_state = Pub(self, Float64MultiArray, 'controller_state', pub_qos, bus)
        self._fb_msg = Float64()
        self._state_msg = Float64MultiArray()
        self._state_msg.layout.dim = [MultiArrayDimension(label=lab, size=1, stride=1)
                                      for lab in STATE_LABELS]
        subscription(self, JointState, 'displacement', self._on_disp,
                     sample_qos(self.lockstep), bus)
        # the reference is the setpoint the compensator accepted (it is the only consumer
        # of ``setpoint``); realtime reads it latched, so a restarted controller has it
        subscription(self, Float64, 'reference', self._on_setpoint,
                     LOCKSTEP_QOS if self.lockstep else REFERENCE_LATCHED_QOS, bus)
        if not self.lockstep:   # realtime: parked while the driver holds its output
            io.watch_driver(self.step.set_held, self.step.drive)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.health = io.serve_health(cycle=not self.lockstep)
        self._stamp_ns = 0              # realtime: stamp (ns) of the sample being answered
        self.wired = self.lockstep      # realtime: the driver and compensator are heard
        self.sp_q, self.y_q = [], []
        self.n_fb = self.n_state = 0
        self.health.summary(OK, 'running (%s)' % self.mode if self.lockstep else
                            'waiting for a setpoint: feedback off (%s)' % self.mode)
        self.get_logger().info('controller ready: mode %s at %g Hz, %s pairing'
                               % (self.mode, self.rate_hz,
                                  'index' if self.lockstep else 'latest-setpoint'))

    # -- parameters -----------------------------------------------------------------
    def _make(self, params):
        """Build the feedback law; realtime: its reference model's lead covers one more T."""
        ctl = build_controller(self.mode, params, self.shaping, self.io.design, self.rate_hz,
                               getattr(self.step.ctl, 'surface', None))
        if ctl is not None and not self.lockstep:
            extend_lead(getattr(ctl, 'reference_filter', None), 1.0 / self.rate_hz)
        return ctl

    def _core_params(self, changes=None):
        flat = {n: self.get_parameter(n).value for n in self.core_names}
        flat.update(changes or {})
        return unflatten(flat)

    def _check(self, changes, params):
        """Return ``None`` or why ``params`` (nested, ``changes`` applied) are refused."""
        return checks.controller_values(changes, params, *self.limits_for)

    def _on_set(self, params):
        """Validate a live update (:mod:`fiber_align.graph.checks`); rebuild, keep state."""
        for p in params:
            if p.name == 'controller_state_every':  # in range (its descriptor): applied
                self.state_every = int(p.value)
        changes = {p.name: p.value for p in params if p.name in self.core_names}
        if not changes:
            return SetParametersResult(successful=True)
        why = self._check(changes, self._core_params(changes))
        if why:
            return SetParametersResult(successful=False, reason=why)
        try:
            new = self._make(self._core_params(changes))
        except (ConfigError, ValueError, KeyError, TypeError) as exc:
            return SetParametersResult(successful=False, reason='%s rejected: %s' % (
                ', '.join(changes), exc))
        if new is not None and self.step.ctl is not None:
            carry_state(self.step.ctl, new)
        self.step.ctl = new
        self.get_logger().info('parameters updated: %s' % ', '.join(p.name for p in params))
        return SetParametersResult(successful=True)

    # -- messages -------------------------------------------------------------------
    def _on_reset(self, request, response):
        """Clear the controller's integral and filters."""
        if self.step.ctl is not None:
            self.step.ctl.reset()
            if not self.lockstep:
                self.step.park()
        response.success, response.message = True, 'controller reset'
        return response

    def _on_setpoint(self, msg):
        why = self.io.take(msg.data)
        if why:
            self.io.report()
        if self.lockstep:
            self.sp_q.append(self.sp.value)
            self._pair()
        elif not why and self.step.setpoint():  # the first: start parked where it is
            self.health.summary(OK, 'running (%s)' % self.mode)

    def _on_disp(self, msg):
        y = msg.position[0] if len(msg.position) else math.nan
        if self.lockstep:
            self.y_q.append(y)
            self._pair()
            return
        self.step.y_latest = y
        if not self.wired and not self._wire():
            return
        st = msg.header.stamp
        self._stamp_ns = stamp_ns(st)
        self._publish(*self.step.sample(st, y, self.sp.value))

    def _wire(self):
        """Realtime: True once the driver and compensator are heard (then start parked)."""
        # a restarted controller that ran before its drive_voltage, drive_held and
        # reference readers matched would wind up blind to a held driver
        self.wired = all(self.count_publishers(self.resolve_topic_name(t)) > 0
                         for t in ('drive_voltage', 'drive_held', 'reference'))
        if self.wired and self.step.ctl is not None:
            self.step.reset()
        return self.wired

    def _pair(self):
        while self.sp_q and self.y_q:
            self._publish(*self.step.step(self.sp_q.pop(0), self.y_q.pop(0)))

    def _publish(self, fb, e, de, gains):
        """Publish the feedback (V) and the controller state (SI)."""
        msg = self._fb_msg
        msg.data = float(fb)
        self.pub_fb.publish(msg)
        self.n_fb += 1
        self.io.latency(self._stamp_ns)     # realtime: sample-to-feedback latency
        if self.state_every and self.n_fb % self.state_every == 0:
            st = self._state_msg
            st.data = [float(e), float(de), float(gains[0]), float(gains[1]),
                       float(gains[2]), float(fb)]
            self.pub_state.publish(st)
            self.n_state += 1
        if self.n_fb % 500 == 0:
            self.io.report(**{'sent.feedback_voltage': self.n_fb,
                              'sent.controller_state': self.n_state, 'mode': self.mode})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'feedback_voltage': self.n_fb, 'controller_state': self.n_state}


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(FuzzyPidControllerNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
