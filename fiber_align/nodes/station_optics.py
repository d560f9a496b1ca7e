# SPDX-License-Identifier: Apache-2.0
"""
``station_optics`` (node ``simulated_station_optics``): the coupled station's output power.

Wraps :class:`fiber_align.plant.station_optics.StationLink` (the input and output facets'
Gaussian overlaps, the chip's loss, the cure's pull, the detector of the 1-D model). Runs
in the station's namespace (``/station``); topics (relative names, SI units):

- sub ``in/x/tip_position``, ``in/y/tip_position``, ``out/x/tip_position``,
  ``out/y/tip_position`` (sensor_msgs/JointState, position[0] in m, stamp = t_k): the true
  tip positions the four plants publish (``tip_position_every`` 1).
- pub ``optical_power`` (std_msgs/Float64, W): one detector reading per sample, per-sample
  QoS.
- ``/diagnostics``: OK, the sample count and the last reading.

Pairing: ``lockstep`` takes the i-th position of every axis and reads the detector at
``t_i = i / rate_hz`` (the offline station bench's ``k T``, bit for bit); ``realtime``
reads on every ``in/x`` sample with the latest position of the other axes, at its stamp.

Parameters (read-only): ``optics.*`` (the source and detector constants of
``config/optics.yaml``, shared with every optics model), the chip, facet and cure keys and
``seed`` (detector noise seed) of ``config/station.yaml``, and the graph-wide
``sync_mode``, ``diagnostics_period_s``, ``rate_hz``, ``realtime_priority``.
"""

import math
import sys

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from fiber_align.graph.registry import NODES, STATION_AXES
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, stamp_to_s, subscription
from fiber_align.nodes.ros.diagnostics import Health, OK
from fiber_align.nodes.rig_optics import declare_optics, OpticsReadings, optics_defaults
from fiber_align.nodes.ros.params import declare, declare_graph_values, node_defaults
from fiber_align.nodes.ros.params import PRIORITY
from fiber_align.nodes.ros.qos import sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.plant import station_optics as so

#: the registry's entry of this node: its name and params files
SPEC = NODES['simulated_station_optics']
#: The station's axes (namespaces below the station's), in the order of the positions.
AXES = STATION_AXES
OPTICS_KEYS = so.SOURCE_KEYS + so.DETECTOR_KEYS


class StationOpticsNode(OpticsReadings, Node):
    """Transport, parameters and health around :class:`~so.StationLink`."""

    def __init__(self, bus=None, **kwargs):
        """Declare the parameters (defaults from config/), build the link, wire topics."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        d.update(optics_defaults(OPTICS_KEYS))
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'rate_hz',
                                 *PRIORITY)
        self.lockstep, diag = g['sync_mode'] == 'lockstep', g['diagnostics_period_s']
        seed, optics = declare_optics(self, d)
        chip = {name: declare(self, d, name, 'chip, facet or cure constant (SI: m, rad, s, '
                              'dB; see station.yaml)', read_only=True)
                for name in so.CHIP_KEYS}
        self.period_s = 1.0 / float(g['rate_hz'])
        over = {k.split('.', 1)[1]: v for k, v in optics.items()}
        over.update(chip, sample_period_s=self.period_s)
        self.link = so.StationLink.from_params(seed=seed, **over)
        self.pub = Pub(self, Float64, 'optical_power', sample_pub_qos(self.lockstep), bus)
        qos = sample_qos(self.lockstep)
        self.q = [[] for _ in AXES]             # lockstep: positions not yet read (m)
        self.latest = [None] * len(AXES)        # realtime: the newest position (m)
        for i, a in enumerate(AXES):
            subscription(self, JointState, a + '/tip_position',
                         lambda msg, i=i: self._on_position(i, msg), qos, bus)
        self.health = Health(self, diag, slack=slack_of(bus), sender=sender_of(bus))
        self.n = 0
        self._msg = Float64()
        self.health.status(OK, 'ready')
        self.get_logger().info('station optics ready (%s pairing), facets at %s um'
                               % ('index' if self.lockstep else 'latest position',
                                  ', '.join('%.2f' % (v * 1e6) for v in
                                            self.link.coupling.peak(0.0))))

    def _on_position(self, i, msg):
        x = float(msg.position[0]) if len(msg.position) else math.nan
        if self.lockstep:
            self.q[i].append(x)
            while all(self.q):
                self._read(self.n * self.period_s, [q.pop(0) for q in self.q])
            return
        self.latest[i] = x
        if i == 0 and all(v is not None for v in self.latest):
            self._read(stamp_to_s(msg.header.stamp), list(self.latest))

    def _measure(self, t_s, pos):
        """Return the detector reading (W) with the fibers at ``pos`` (four, m) at ``t_s``."""
        return self.link.measure(t_s, pos, self.period_s)


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(StationOpticsNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
