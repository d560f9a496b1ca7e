# SPDX-License-Identifier: Apache-2.0
"""
``hysteresis_compensator``: the feedforward (inverse PI model) as a ROS 2 node.

``ff = Feedforward.step(r)`` (V from m) of :mod:`fiber_align.control.feedforward`, the
exact inverse of the Prandtl-Ishlinskii model, after the optional resonance-suppression
shaper (``shaping``: none | zv | zvd), built by :func:`fiber_align.control.factory.
build_feedforward` for the graph's ``controller``, exactly the offline loop's feedforward.

It steps (shaper and inverse model advance once per period):

- ``lockstep`` and ``sensorless`` (the hardware graph): one ``feedforward_voltage``
  (std_msgs/Float64, V) per ``setpoint`` (std_msgs/Float64, m), so index pairing holds;
- ``realtime``: one ``feedforward_voltage`` per ``displacement`` sample (sensor_msgs/
  JointState, newest only), towards the latest valid setpoint along the realtime setpoint
  trajectory; the step rules (drive held, a stall, a stale drive) are
  :class:`fiber_align.control.realtime.CompensatorStep`'s, the delay compensation
  predicts the realtime loop's one extra period. While the driver reports ``drive_held``
  the compensator rests at the measured position (the drive returns through the shaper).

An accepted setpoint is passed on as ``reference`` (std_msgs/Float64, m; realtime latched)
for the controller, so the feedforward and the feedback follow the same reference. A NaN,
infinite or out-of-range setpoint (outside ``[setpoint_min_m, setpoint_max_m]``) is
refused with a logged reason and a WARN; the last valid one is used in its place.

Parameters: the model (``thresholds_v``, ``weights_m_per_v``) inline or in ``model_file``
(a params file of ``PIModel.save``; one that names no readable, invertible model is
refused at start-up and when set, :mod:`fiber_align.graph.checks`), the shaping and
``controller`` (graph-wide). Services (std_srvs/Trigger): ``~/reload_model`` reads the
model again, keeping the old one when the new one fails; ``~/reset`` restarts the
feedforward at rest at the present position. docs/ros_interface.md has the details.
"""

import sys

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from fiber_align.config import ConfigError
from fiber_align.control.factory import build_feedforward
from fiber_align.control.realtime import CompensatorStep, extend_lead
from fiber_align.control.trajectory import stamp_ns
from fiber_align.graph import checks
from fiber_align.graph.ranges import COMPENSATOR_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.hysteresis.pi import PIModel
from fiber_align.nodes.ros.bus import Pub, subscription
from fiber_align.nodes.ros.diagnostics import OK
from fiber_align.nodes.ros.loop_io import LoopIO
from fiber_align.nodes.ros.params import declare, declare_row, node_defaults
from fiber_align.nodes.ros.qos import CONTROL_QOS, LOCKSTEP_QOS, REALTIME_QOS
from fiber_align.nodes.ros.qos import sample_pub_qos, SETPOINT_QOS
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['hysteresis_compensator']
#: The node's own parameters: name -> description (read-only but the model's).
OWN = {'model_file': 'PI model params file; empty: the inline model',
       'model_source': 'where the inline model comes from',
       'thresholds_v': 'PI play-operator thresholds (V)',
       'weights_m_per_v': 'PI weights (m/V)'}


class HysteresisCompensatorNode(Node):
    """Transport, parameters and the reload service around :class:`Feedforward`."""

    def __init__(self, bus=None, **kwargs):
        """Load the model of the parameters (config/ defaults), wire topics (``bus``: LocalBus)."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        io = self.io = LoopIO(self, d, bus, 'sensorless')    # graph values, shaping, ...
        g, self.shaping, self.sp = io.g, io.shaping, io.sp
        self.rate_hz, self.lockstep = io.rate_hz, io.lockstep
        # sensorless (the hardware graph): no displacement to clock it; one feedforward
        # per setpoint, as in lockstep (the sequencer steps once per power reading)
        self.per_setpoint = self.lockstep or bool(g['sensorless'])
        for name, text in OWN.items():
            declare(self, d, name, text)
        why = self._check_model({})
        if why:
            raise ConfigError('hysteresis_compensator: %s' % why)
        self.add_on_set_parameters_callback(self._on_set)
        self.open_loop_gain = declare_row(self, d, COMPENSATOR_RANGES, 'open_loop_gain_v_per_m')
        self.pub = Pub(self, Float64, 'feedforward_voltage', sample_pub_qos(self.lockstep),
                       bus, slack=io.slack)
        # the accepted setpoint for the controller (one consumer of ``setpoint``); realtime
        # publishes it on change, transient local: a restarted controller gets the present
        self.pub_ref = Pub(self, Float64, 'reference', CONTROL_QOS, bus,
                           latched=not self.lockstep)
        self._msg = Float64()
        self._ref_msg = Float64()
        self.n_ref = 0
        # lockstep: transient local, so the first setpoint of the source (published as
        # soon as it matched) is not lost if this reader matched a moment later
        subscription(self, Float64, 'setpoint', self._on_setpoint,
                     LOCKSTEP_QOS if self.lockstep else SETPOINT_QOS, bus)
        if not self.per_setpoint:
            subscription(self, JointState, 'displacement', self._on_sample,
                         REALTIME_QOS, bus)
            # held: rest at the measured position; a drive: the loop is closed
            io.watch_driver(lambda held: setattr(self.step, 'held', held),
                            lambda: self.step.drive())
        self.create_service(Trigger, '~/reload_model', self._on_reload)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.health = io.serve_health(cycle=True)
        self.n_ff = 0
        self.step = CompensatorStep(self.build(), *io.step_args())
        self.health.summary(OK, 'ready (%s)' % g['controller'])
        self.get_logger().info('compensator ready: %s, shaping %s, model %s' % (
            g['controller'], self.shaping['shaping'], self.model_name()))

    def _check_model(self, changes):
        """Return ``None`` or why the model parameters (``changes`` applied) are refused."""
        v = {n: changes.get(n, self.get_parameter(n).value)
             for n in ('model_file', 'thresholds_v', 'weights_m_per_v')}
        if 'model_file' in changes or not changes:
            why = checks.model_file(v['model_file'])
            if why:
                return why
        if 'thresholds_v' in changes or 'weights_m_per_v' in changes or not changes:
            return checks.pi_model(v['thresholds_v'], v['weights_m_per_v'])
        return None

    def _on_set(self, params):
        """
        Refuse a model that cannot be used (:mod:`fiber_align.graph.checks`).

        A ``model_file`` must name a readable, invertible model file ('' the inline
        model), the inline lists an invertible model; ``~/reload_model`` then loads it.
        """
        changes = {p.name: p.value for p in params if p.name in OWN}
        why = self._check_model(changes) if changes else None
        if why:
            return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    def model_name(self):
        """Return where the model comes from (file path or ``inline``)."""
        return self.get_parameter('model_file').value or 'inline'

    def load_model(self):
        """Return the PI model of the parameters (or of ``model_file``)."""
        path = self.get_parameter('model_file').value
        if path:
            return PIModel.load(path)
        return PIModel([float(x) for x in self.get_parameter('thresholds_v').value],
                       [float(x) for x in self.get_parameter('weights_m_per_v').value])

    def build(self):
        """Return a fresh :class:`Feedforward` (V from m) for the parameters."""
        comp = dict(self.shaping, open_loop_gain_v_per_m=self.open_loop_gain)
        ff = build_feedforward(self.get_parameter('controller').value, comp,
                               self.load_model(), self.io.design, self.rate_hz)
        if not self.per_setpoint:
            extend_lead(ff, 1.0 / self.rate_hz)    # the realtime loop's extra period
        return ff

    def _on_reload(self, request, response):
        """Reload the model; keep the old one if the new one fails."""
        try:
            ff = self.build()
        except (ConfigError, ValueError, OSError, KeyError) as exc:
            response.success = False
            response.message = 'kept the old model: %s' % exc
            self.get_logger().error(response.message)
            self.health.warn(response.message)
            return response
        ff.start_at(self.sp.value)   # the new inverse settled at the present setpoint
        self.step.ff = ff
        response.success = True
        response.message = 'model reloaded from %s' % self.model_name()
        self.get_logger().info(response.message)
        return response

    def _on_setpoint(self, msg):
        """
        Take the user's setpoint (m): this node is its only consumer.

        An accepted setpoint is passed on as ``reference`` for the controller, so the
        feedforward and the feedback always follow the same reference (a setpoint either
        reaches the whole loop or none of it). Lockstep passes one ``reference`` per
        setpoint (the held one in place of a rejected one, so pairing holds).
        """
        why = self.io.take(msg.data)
        if why:
            self._update_values()
            if not self.per_setpoint:
                return
        ref = self._ref_msg
        ref.data = self.sp.value
        self.pub_ref.publish(ref)
        self.n_ref += 1
        if self.per_setpoint:
            self._publish(self.step.ff.step(self.sp.value))

    def _on_sample(self, msg):
        """Realtime: step the feedforward (:class:`CompensatorStep`); count the latency."""
        st = msg.header.stamp
        self._publish(self.step.sample(st, msg.position[0] if len(msg.position) else None,
                                       self.sp.value))
        self.io.latency(stamp_ns(st))

    def _on_reset(self, request, response):
        """Restart the feedforward at rest at the present position (m)."""
        y = max(0.0, self.sp.value) if self.per_setpoint else self.step.present()
        self.step.rest(y)
        response.success = True
        response.message = 'feedforward restarted at %.6g m' % y
        self.get_logger().info(response.message)
        return response

    def _publish(self, v):
        """Publish the feedforward voltage ``v`` (V)."""
        msg = self._msg
        msg.data = float(v)
        self.pub.publish(msg)
        self.n_ff += 1
        if self.n_ff % 500 == 0:
            self._update_values()

    def _update_values(self):
        """Report counts and the held setpoint (m) on ``/diagnostics``."""
        self.io.report(**{'sent.feedforward_voltage': self.n_ff})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'feedforward_voltage': self.n_ff, 'reference': self.n_ref}


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(HysteresisCompensatorNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
