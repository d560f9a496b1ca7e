# SPDX-License-Identifier: Apache-2.0
"""
``alignment_sequencer2d`` (node ``alignment_sequencer_2d``): the rig's two-axis setpoints.

Wraps :class:`fiber_align.alignment.sequencer2d.Sequencer2D` (one ``update`` per sample:
spiral first light, paraboloid peak fit, circular-dither tracking; docs/alignment2d.md).
Runs in the rig's namespace (``/rig``); topics and services (relative names, SI units):

- sub ``x/displacement``, ``y/displacement`` (sensor_msgs/JointState, position[0] the
  sensor reading in m, stamp = t_k) and ``optical_power`` (std_msgs/Float64, W, from
  ``rig_optics``).
- pub ``x/setpoint``, ``y/setpoint`` (std_msgs/Float64, m): exactly one each per sample;
  each axis's ``hysteresis_compensator`` is their one consumer.
- pub ``alignment_state`` (std_msgs/String, JSON: ``Sequencer2D.status()`` plus
  ``sample``, the index of the next update, ``sample_time_s``, the time of the last one
  (s), and ``align_sample``, the index of the update the last accepted ``align`` acted
  before), latched, on every change of state or fault and after every command.
- ``/diagnostics``: OK in IDLE, SEARCHING, PEAKING, TRACKING, RELEASING; ERROR in FAULT.
- srv ``align``, ``release`` (std_srvs/Trigger); ``switch`` (std_srvs/SetBool).
- sub ``/diagnostics``: a status of ``x/actuator_driver`` or ``y/actuator_driver`` (this
  namespace) at ERROR or above is passed to the core as ``driver_active=False``.

Pairing: ``lockstep`` pairs the i-th x, y and power and calls ``update`` with
``t_i = i * control_period_s`` (the offline bench's time, bit for bit: the plants stamp
the same ``i T`` to the ns); a command (service) acts before the next update, whose index
``alignment_state`` reports as ``sample``. If no power arrives, positions wait at most
``power_queue_limit`` samples and are then processed without power (the core reports
"sensor silent"). ``realtime`` steps on every x sample (its stamp is t) with the latest
y and the power received since the previous step, or none.
"""

import math
import sys

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from fiber_align.alignment import sequencer2d as s2d
from fiber_align.config import load_params
from fiber_align.nodes import _common as c
from fiber_align.nodes._sequencer_node import SequencerNode
from fiber_align.nodes.alignment_sequencer import POWER_QUEUE_LIMIT

NODE_NAME = s2d.CONFIG_NODE         # alignment_sequencer_2d
AREA_FILES = (s2d.CONFIG_FILE,)
AXES = ('x', 'y')
#: Topics this node publishes (relative names; see ``_common.LocalBus``).
PUBLISHES = ('x/setpoint', 'y/setpoint')


class AlignmentSequencer2DNode(SequencerNode, Node):
    """Transport, services and health around the pure :class:`~s2d.Sequencer2D`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare every key of ``sequencer2d.yaml`` (read-only), build the core, wire both axes.

        :param bus: the ``LocalBus`` of the rig's composed process, or ``None``.
        """
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        self.lockstep, diag = c.declare_sync(self, d)
        core = {name: c.declare(self, d, name, 'sequencer parameter (SI, see '
                                'sequencer2d.yaml)', read_only=True)
                for name in load_params(s2d.CONFIG_FILE, s2d.CONFIG_NODE)}
        self.seq = s2d.Sequencer2D(core)
        self.period_s = float(core['control_period_s'])
        self.pub_sp = [c.Pub(self, Float64, a + '/setpoint', c.CONTROL_QOS, bus)
                       for a in AXES]
        qos = c.sample_qos(self.lockstep)
        c.subscription(self, JointState, 'x/displacement', self._on_x, qos, bus)
        c.subscription(self, JointState, 'y/displacement', self._on_y, qos, bus)
        c.subscription(self, Float64, 'optical_power', self._on_power, qos, bus)
        self._serve()
        self.health = c.Health(self, diag)
        ns = self.get_namespace().rstrip('/')
        self.drivers = {'%s/%s/actuator_driver' % (ns, a): None for a in AXES}
        self.q = {'x': [], 'y': [], 'p': []}
        self.y_latest = None
        self.n = 0                      # updates done = index of the next sample
        self.align_sample = None
        self.t_last = None              # time (s) of the last update
        self._publish_state()
        self.get_logger().info('2-D sequencer ready (%s pairing)'
                               % ('index' if self.lockstep else 'latest y and power'))

    # -- inputs ---------------------------------------------------------------------
    @staticmethod
    def _position(msg):
        return msg.position[0] if len(msg.position) else math.nan

    def _on_x(self, msg):
        if self.lockstep:
            self.q['x'].append(self._position(msg))
            self._pair()
            return
        p = self.q['p'][-1] if self.q['p'] else None
        self.q['p'] = []
        self._step(c.stamp_to_s(msg.header.stamp), self._position(msg), self.y_latest, p)

    def _on_y(self, msg):
        if self.lockstep:
            self.q['y'].append(self._position(msg))
            self._pair()
        else:
            self.y_latest = self._position(msg)

    def _on_power(self, msg):
        self.q['p'].append(float(msg.data))
        if self.lockstep:
            self._pair()

    def _pair(self):
        q = self.q
        while q['x'] and q['y'] and q['p']:
            self._step(self.n * self.period_s, q['x'].pop(0), q['y'].pop(0), q['p'].pop(0))
        while len(q['x']) > POWER_QUEUE_LIMIT and q['y']:
            self._step(self.n * self.period_s, q['x'].pop(0), q['y'].pop(0), None)

    def _driver_report(self, name, ok):
        if name in self.drivers:
            self.drivers[name] = ok

    def driver_active(self):
        """Return False when a driver reports ERROR, True when both are fine, else None."""
        v = list(self.drivers.values())
        return False if False in v else (True if all(v) else None)

    # -- the step -------------------------------------------------------------------
    def _step(self, t, x, y, p):
        def ok(v):
            return v if v is not None and math.isfinite(v) else None
        rx, ry = self.seq.update(t, ok(x), ok(y), p, driver_active=self.driver_active())
        self.n += 1
        self.t_last = t
        for pub, r in zip(self.pub_sp, (rx, ry)):
            pub.publish(Float64(data=float(r)))
        self._publish_state()

    def _publish_state(self):
        s = self.seq.status()
        # as the 1-D node: the sample time (s) of the last update, for a lagging observer
        s.update(sample=self.n, align_sample=self.align_sample, sample_time_s=self.t_last)
        self._publish_status(s, aligned_x_m=s['aligned_x_m'], aligned_y_m=s['aligned_y_m'],
                             sample=self.n)

    def _command_align(self):
        result = self.seq.align()
        if result[0]:
            self.align_sample = self.n
        return result

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'x/setpoint': self.n, 'y/setpoint': self.n, 'alignment_state': self.n_state}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return c.run_node(AlignmentSequencer2DNode, NODE_NAME, args)


if __name__ == '__main__':
    sys.exit(main())
