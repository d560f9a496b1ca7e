# SPDX-License-Identifier: Apache-2.0
"""
``rig_optics`` (node ``simulated_optics_2d``): the coupled power of the two-axis rig.

Wraps :class:`fiber_align.plant.optics2d.OpticalLink2D` (the Gaussian overlap of an
(x, y) offset, the moving target, the detector of the 1-D model). Runs in the rig's
namespace (``/rig``); topics (relative names, SI units):

- sub ``x/tip_position``, ``y/tip_position`` (sensor_msgs/JointState, position[0] in m,
  stamp = t_k): the true tip positions the two plants publish (``tip_position_every`` 1).
- pub ``optical_power`` (std_msgs/Float64, W): one detector reading per sample pair,
  per-sample QoS.
- ``/diagnostics``: OK, the sample count and the last reading.

Pairing: ``lockstep`` pairs the i-th x with the i-th y position and reads the detector at
``t_i = i / rate_hz`` (the offline bench's ``k T``, bit for bit), one
reading per pair, so the sequencer gets exactly the offline run's power. ``realtime``
reads the detector on every x sample with the latest y position, at the x stamp's time.

Parameters (read-only): ``optics.*`` (the link and detector constants of
``config/optics.yaml``, shared with the 1-D plant), ``target.*`` and ``seed`` (detector
noise seed) of ``config/optics2d.yaml``, and the graph-wide ``sync_mode``,
``diagnostics_period_s``, ``realtime_priority``.
"""

import math
import sys

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, stamp_to_s, subscription
from fiber_align.nodes.ros.diagnostics import Health, OK
from fiber_align.nodes.ros.params import declare, declare_graph_values, flatten_defaults
from fiber_align.nodes.ros.params import node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.plant import optics as op, optics2d as o2

#: the registry's entry of this node: its name and params files
SPEC = NODES['simulated_optics_2d']
OPTICS_KEYS = o2.LINK_KEYS + o2.DETECTOR_KEYS


def optics_defaults(keys=OPTICS_KEYS):
    """Return the ``optics.*`` defaults (dotted names) of ``config/optics.yaml`` in ``keys``."""
    flat = flatten_defaults(node_defaults(op.CONFIG_NODE), op.CONFIG_KEY)
    return {k: v for k, v in flat.items() if k.split('.', 1)[1] in keys}


def declare_optics(node, d):
    """
    Declare ``seed`` and every ``optics.*`` of the defaults ``d``, read-only.

    :returns: ``(seed, {dotted name: value})``.
    """
    seed = declare(node, d, 'seed', 'detector noise seed', 0, 2 ** 31 - 1, True)
    optics = {name: declare(node, d, name, 'optics constant (SI, see optics.yaml)',
                            read_only=True)
              for name in sorted(k for k in d if k.startswith('optics.'))}
    return int(seed), optics


class OpticsReadings:
    """
    One detector reading per sample, published (the rig's and the station's optics nodes).

    The node has ``pub``, ``_msg`` (a Float64), ``n``, ``health`` and ``_measure(t_s, pos)``.
    """

    def _read(self, t_s, pos):
        """Publish one detector reading (W) with the fibers at ``pos`` (m) at ``t_s``."""
        if not all(math.isfinite(v) for v in pos):
            # refused, not read: a NaN would stay in the detector's averaging for good;
            # a NaN reading still goes out so that the index pairing holds
            why = 'tip positions %r m: not all numbers, no reading' % (tuple(pos),)
            self.get_logger().warning(why)
            self.health.warn(why)
            self._msg.data = math.nan
        else:
            self._msg.data = float(self._measure(t_s, pos))
        self.pub.publish(self._msg)
        self.n += 1
        self.health.set_values(samples=self.n, optical_power_w=self._msg.data)

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'optical_power': self.n}


class RigOpticsNode(OpticsReadings, Node):
    """Transport, parameters and health around :class:`~o2.OpticalLink2D`."""

    def __init__(self, bus=None, **kwargs):
        """Declare the parameters (defaults from config/), build the link, wire topics."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        d.update(optics_defaults())
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'rate_hz',
                                 *PRIORITY)
        self.lockstep, diag = g['sync_mode'] == 'lockstep', g['diagnostics_period_s']
        seed, optics = declare_optics(self, d)
        target = {}
        for name, value in sorted(flatten_defaults(d, 'target').items()):
            target[name] = declare(self, {name: value}, name, 'target (output core) '
                                   'motion (SI: m, m/s, Hz, rad; see optics2d.yaml)',
                                   read_only=True)
        self.period_s = 1.0 / float(g['rate_hz'])
        self.link = o2.OpticalLink2D.from_params(optics, target, seed=int(seed),
                                                 sample_period_s=self.period_s)
        self.pub = Pub(self, Float64, 'optical_power', sample_pub_qos(self.lockstep), bus)
        qos = sample_qos(self.lockstep)
        subscription(self, JointState, 'x/tip_position', self._on_x, qos, bus)
        subscription(self, JointState, 'y/tip_position', self._on_y, qos, bus)
        self.health = Health(self, diag, slack=slack_of(bus), sender=sender_of(bus))
        self.x_q, self.y_q = [], []
        self.y_latest = None
        self.n = 0
        self._msg = Float64()
        self.health.status(OK, 'ready')
        self.get_logger().info('rig optics ready (%s pairing), target at (%.2f, %.2f) um'
                               % ('index' if self.lockstep else 'latest y',
                                  self.link.coupling.target.position(0.0)[0] * 1e6,
                                  self.link.coupling.target.position(0.0)[1] * 1e6))

    @staticmethod
    def _position(msg):
        return float(msg.position[0]) if len(msg.position) else math.nan

    def _on_x(self, msg):
        if self.lockstep:
            self.x_q.append(self._position(msg))
            self._pair()
        elif self.y_latest is not None:
            self._read(stamp_to_s(msg.header.stamp), (self._position(msg), self.y_latest))

    def _on_y(self, msg):
        if self.lockstep:
            self.y_q.append(self._position(msg))
            self._pair()
        else:
            self.y_latest = self._position(msg)

    def _pair(self):
        while self.x_q and self.y_q:
            self._read(self.n * self.period_s, (self.x_q.pop(0), self.y_q.pop(0)))

    def _measure(self, t_s, pos):
        """Return the detector reading (W) with the tip at ``pos`` = (x, y) (m) at ``t_s``."""
        return self.link.measure(t_s, pos[0], pos[1], self.period_s)


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(RigOpticsNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
