# SPDX-License-Identifier: Apache-2.0
"""
``simulated_optics``: the detector reading of a multi-axis machine's optical link.

One executable for every link, chosen by the read-only parameter ``link``: ``rig``
(:class:`~fiber_align.plant.optics2d.OpticalLink2D`, node ``simulated_optics_2d``),
``station`` (:class:`~fiber_align.plant.station_optics.StationLink`), ``array``
(:class:`~fiber_align.plant.array_optics.ArrayLink`), in the machine's namespace. Topics
(relative names, SI units):

- sub ``<a>/tip_position`` per axis (sensor_msgs/JointState, position[0] m, stamp t_k).
- pub ``optical_power`` (std_msgs/Float64, W; the array: channel 1, channel N on
  ``optical_power_n``): a reading per sample; a position that is not a number gives a NaN
  reading (kept out of the detector's averaging) and a WARN.
- pub ``array_model`` (the array; std_msgs/Float64MultiArray, one dim per value labelled
  by :func:`~fiber_align.plant.array_optics.model_labels`), every ``model_period_s``: the
  pose and the best joint pose (m, m, rad), every channel's coupling (0..1) there and at
  the best pose (for the live view and the report).

Pairing: ``lockstep`` reads the i-th position of every axis at ``t_i = i / rate_hz`` (the
offline bench, bit for bit); ``realtime`` reads on every sample of the first axis with
the latest of the others. Parameters: read-only but ``meter_frozen`` (fault injection:
the last reading repeated); ``link``, ``seed``, ``optics.*`` (``optics.yaml``), the link's
own keys (``optics2d.yaml``, ``station.yaml``, ``array.yaml``) and the graph-wide ones.
"""

import math
import sys

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension as Dim
from std_msgs.msg import MultiArrayLayout

from fiber_align.control.trajectory import stamp_to_s
from fiber_align.graph.ranges import ARRAY_OPTICS_RANGES, OPTICS_RANGES
from fiber_align.graph.registry import ARRAY_AXES, ARRAY_POWERS, STATION_AXES
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, subscription
from fiber_align.nodes.ros.diagnostics import Health, OK
from fiber_align.nodes.ros.params import declare, declare_graph_values, declare_row
from fiber_align.nodes.ros.params import flatten_defaults
from fiber_align.nodes.ros.params import node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.plant import array_optics as ao
from fiber_align.plant import optics as op, optics2d as o2, station_optics as so

#: Each link: its axes (namespaces below the node's, in the order of the positions),
#: its params file and the ``optics.*`` keys of ``config/optics.yaml`` it reads.
LINKS = {
    'rig': (('x', 'y'), o2.CONFIG_FILE, o2.LINK_KEYS + o2.DETECTOR_KEYS),
    'station': (STATION_AXES, so.CONFIG_FILE, so.SOURCE_KEYS + so.DETECTOR_KEYS),
    'array': (ARRAY_AXES, ao.CONFIG_FILE, ao.SOURCE_KEYS + so.DETECTOR_KEYS),
}


class SimulatedOpticsNode(Node):
    """Transport, parameters and health around a machine's optical link."""

    NAME = 'simulated_optics_2d'

    def __init__(self, bus=None, **kwargs):
        """Declare the parameters, build the link, wire the axes (``bus``: a LocalBus or None)."""
        super().__init__(self.NAME, **kwargs)
        d = node_defaults(self.get_name(), tuple(f for _, f, _ in LINKS.values()))
        self.link_name = declare(self, d, 'link', 'the optical link simulated',
                                 read_only=True, choices=tuple(LINKS))
        axes, _, keys = LINKS[self.link_name]
        flat = flatten_defaults(node_defaults(op.CONFIG_NODE), op.CONFIG_KEY)
        d.update({k: v for k, v in flat.items() if k.split('.', 1)[1] in keys})
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'rate_hz',
                                 *PRIORITY)
        self.lockstep, self.period_s = g['sync_mode'] == 'lockstep', 1.0 / g['rate_hz']
        seed = int(declare_row(self, d, OPTICS_RANGES, 'seed'))
        optics = {name: declare(self, d, name, 'optics constant (SI, see optics.yaml)',
                                read_only=True)
                  for name in sorted(k for k in d if k.startswith('optics.'))}
        self.model_every, self.model = 0, None     # the array: its model, published
        self.link = getattr(self, '_' + self.link_name)(d, seed, optics)
        self.topics = ARRAY_POWERS if self.link_name == 'array' else ARRAY_POWERS[:1]
        out = sample_pub_qos(self.lockstep)
        self.pubs = [Pub(self, Float64, topic, out, bus) for topic in self.topics]
        if self.model_every:    # one labelled dim per value, as controller_state
            self.model_pub = Pub(self, Float64MultiArray, 'array_model', out, bus)
            self._model_msg = Float64MultiArray(layout=MultiArrayLayout(dim=[
                Dim(label=k, size=1, stride=1) for k in ao.model_labels(self.model.n)]))
        qos = sample_qos(self.lockstep)
        self.q = [[] for _ in axes]             # lockstep: positions not yet read (m)
        self.latest = [None] * len(axes)        # realtime: the newest position (m)
        for i, a in enumerate(axes):
            subscription(self, JointState, a + '/tip_position',
                         lambda msg, i=i: self._on_position(i, msg), qos, bus)
        self.health = Health(self, g['diagnostics_period_s'], slack=slack_of(bus),
                             sender=sender_of(bus))
        self.frozen = declare(self, d, 'meter_frozen', 'fault injection: every reading '
                              'repeats the last one, a frozen meter (bool, live)')
        self._last, self.n = None, 0            # the last readings (W), one per topic
        self.add_on_set_parameters_callback(self._on_set)
        # one message per topic: the DDS copy is written off this thread, after the loop
        self._msgs = [Float64() for _ in self.pubs]
        self.health.summary(OK, 'ready')
        self.get_logger().info('%s optics ready (%s)' % (self.link_name, g['sync_mode']))

    # -- the links ----------------------------------------------------------------------
    def _rig(self, d, seed, optics):
        """Return the rig's link: ``optics.*`` and the ``target.*`` motion (SI)."""
        target = {name: declare(self, {name: value}, name, 'target (output core) motion '
                                '(SI: m, m/s, Hz, rad; see optics2d.yaml)', read_only=True)
                  for name, value in sorted(flatten_defaults(d, 'target').items())}
        link = o2.OpticalLink2D.from_params(optics, target, seed=seed,
                                            sample_period_s=self.period_s)
        self.measure = lambda t, pos: link.measure(t, pos[0], pos[1], self.period_s)
        return link

    def _station(self, d, seed, optics):
        """Return the station's link: ``optics.*`` and the chip, facet and cure keys (SI)."""
        return self._keyed(d, seed, optics, so.StationLink, so.CHIP_KEYS,
                           'chip, facet or cure constant (SI: m, rad, s, dB; see station.yaml)')

    def _array(self, d, seed, optics):
        """Return the array's link: ``optics.*`` and the geometry, chip and layout keys."""
        link = self._keyed(d, seed, optics, ao.ArrayLink, ao.ARRAY_KEYS, 'array geometry, '
                           'chip pose or layout (SI: m, rad; see array.yaml)')
        every = declare_row(self, d, ARRAY_OPTICS_RANGES, 'model_period_s') / self.period_s
        self.model_every, self.model = every and max(1, int(round(every))), link.coupling
        link.coupling.model(0.0, (0.0, 0.0, 0.0))   # the best pose's fit (0.3 s): not in a tick
        return link

    def _keyed(self, d, seed, optics, cls, keys, what):
        """Return ``cls.from_params`` of ``optics.*`` and the declared ``keys``."""
        over = {k.split('.', 1)[1]: v for k, v in optics.items()}
        over.update({name: declare(self, d, name, what, read_only=True) for name in keys},
                    sample_period_s=self.period_s)
        link = cls.from_params(seed=seed, **over)
        self.measure = lambda t, pos: link.measure(t, pos, self.period_s)
        return link

    # -- readings -----------------------------------------------------------------------
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

    def _read(self, t_s, pos):
        """Publish one detector reading (W) with the fibers at ``pos`` (m) at ``t_s``."""
        if not all(math.isfinite(v) for v in pos):
            # refused, not read: a NaN would stay in the detector's averaging for good;
            # a NaN reading still goes out so that the index pairing holds
            why = 'tip positions %r m: not all numbers, no reading' % (tuple(pos),)
            self.get_logger().warning(why)
            self.health.warn(why)
            values = [math.nan] * len(self.pubs)
        else:
            values = list(np.atleast_1d(self.measure(t_s, pos)))
            if self.frozen and self._last is not None:
                values = self._last     # the detector runs on: its noise stream holds
            self._last = values
        for pub, msg, v in zip(self.pubs, self._msgs, values):
            msg.data = float(v)
            pub.publish(msg)
        if self.model_every and self.n % self.model_every == 0 and math.isfinite(values[0]):
            self._model_msg.data = self.model.model(t_s, pos)     # after the loop's readings
            self.model_pub.publish(self._model_msg)
        self.n += 1
        self.health.set_values(samples=self.n, optical_power_w=float(values[0]))

    def _on_set(self, params):
        """Take ``meter_frozen`` live: a standing WARN on ``/diagnostics`` while it holds."""
        for p in params:
            if p.name == 'meter_frozen' and bool(p.value) != self.frozen:
                self.frozen = bool(p.value)
                why = 'meter_frozen: every reading repeats the last one (fault injection)'
                if self.frozen:
                    self.get_logger().warning(why)
                else:
                    self.get_logger().info('meter_frozen false: live readings again')
                self.health.condition('meter_frozen', why if self.frozen else None)
        return SetParametersResult(successful=True)

    def sent_counts(self):
        """Return published message counts per topic."""
        return {topic: self.n for topic in self.topics}


class StationOpticsNode(SimulatedOpticsNode):
    """The node ``simulated_station_optics`` (``link`` station) as ``control_graph`` hosts it."""

    NAME = 'simulated_station_optics'


class ArrayOpticsNode(SimulatedOpticsNode):
    """The node ``simulated_array_optics`` (``link`` array) as ``control_graph`` hosts it."""

    NAME = 'simulated_array_optics'


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(SimulatedOpticsNode, SimulatedOpticsNode.NAME, args)


if __name__ == '__main__':
    sys.exit(main())
