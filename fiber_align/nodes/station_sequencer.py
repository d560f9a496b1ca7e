# SPDX-License-Identifier: Apache-2.0
"""
``station_sequencer`` (node ``station_sequencer``): the coupled station's four setpoints.

Wraps :class:`fiber_align.alignment.station.Station` (one ``update`` per sample: the joint
first-light search, the joint peak fit of both sides, two-dither tracking;
docs/station.md). Runs in the station's namespace (``/station``); topics and services
(relative names, SI units):

- sub ``in/x/displacement``, ``in/y/displacement``, ``out/x/displacement``,
  ``out/y/displacement`` (sensor_msgs/JointState, position[0] the sensor reading in m,
  stamp = t_k) and ``optical_power`` (std_msgs/Float64, W, from ``station_optics``).
- pub ``in/x/setpoint`` ... ``out/y/setpoint`` (std_msgs/Float64, m): exactly one each
  per sample; each axis's ``hysteresis_compensator`` is their one consumer.
- pub ``alignment_state`` (std_msgs/String, JSON: ``Station.status()`` plus ``sample``,
  the index of the next update, ``sample_time_s``, the time of the last one (s), and
  ``align_sample``, the index of the update the last accepted ``align`` acted before),
  latched, on every change of state or fault and after every command.
- ``/diagnostics``: OK in IDLE, SEARCHING, PEAKING, TRACKING, RELEASING; WARN with the
  reason in HELD; ERROR in FAULT.
- the four drivers' state (``_sequencer_node``): ``<axis>/drive_held``,
  ``<axis>/actuator_driver/transition_event`` and their ``/diagnostics``: a driver that
  stops driving puts an active state in HELD at once (every setpoint held, the axis
  named; a re-peak or a new search once it drives again, FAULT after
  ``driver_down_timeout_s``); ``align`` and ``switch`` true are refused while one is down.
- srv ``align``, ``release`` (std_srvs/Trigger); ``switch`` (std_srvs/SetBool).

Pairing: ``lockstep`` takes the i-th reading of every axis and of the power and calls
``update`` with ``t_i = i / rate_hz`` (the offline station bench's time, bit for bit); a
command (service) acts before the next update, whose index ``alignment_state`` reports
as ``sample``. If no power arrives, positions wait at most ``power_queue_limit`` samples
and are then processed without power (the core reports "sensor silent"). ``realtime``
steps on every ``in/x`` sample (its stamp is t) with the latest reading of the other
axes and the power received since the previous step, or none.
"""

import math
import sys

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from fiber_align.alignment import station as st
from fiber_align.graph.registry import NODES
from fiber_align.nodes._sequencer_node import SequencerNode
from fiber_align.nodes.alignment_sequencer import POWER_QUEUE_LIMIT
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, stamp_to_s, subscription
from fiber_align.nodes.ros.diagnostics import Health
from fiber_align.nodes.ros.params import declare_graph_values, node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.nodes.station_optics import AXES

#: the registry's entry of this node: its name and params files
SPEC = NODES['station_sequencer']


class StationSequencerNode(SequencerNode, Node):
    """Transport, services and health around the pure :class:`~st.Station`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare every key of node ``station_sequencer`` (read-only), build the core, wire.

        :param bus: the ``LocalBus`` of the station's composed process, or ``None``.
        """
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'rate_hz',
                                 'realtime_setpoint_rate_m_per_s', *PRIORITY)
        self.lockstep, diag = g['sync_mode'] == 'lockstep', g['diagnostics_period_s']
        self.period_s = 1.0 / float(g['rate_hz'])
        # realtime: the search walks no faster than the loop's path follows a setpoint
        rate = None if self.lockstep else g['realtime_setpoint_rate_m_per_s']
        self.seq = st.Station(self._declare_core(d, st.CONFIG_FILE, st.CONFIG_NODE),
                              period_s=self.period_s, path_rate_m_per_s=rate)
        self.pub_sp = [Pub(self, Float64, a + '/setpoint', sample_pub_qos(self.lockstep), bus)
                       for a in AXES]
        qos = sample_qos(self.lockstep)
        for i, a in enumerate(AXES):
            subscription(self, JointState, a + '/displacement',
                         lambda msg, i=i: self._on_position(i, msg), qos, bus)
        subscription(self, Float64, 'optical_power', self._on_power, qos, bus)
        self._serve()
        self.health = Health(self, diag, slack=slack_of(bus), sender=sender_of(bus))
        self.q = [[] for _ in AXES]     # lockstep: readings not yet used (m)
        self.q_p = []                   # power readings not yet used (W)
        self.latest = [None] * len(AXES)
        self.n = 0                      # updates done = index of the next sample
        self.align_sample = None
        self.t_last = None              # time (s) of the last update
        self._watch_drivers({name: a + '/' for name, a in zip(st.DRIVERS, AXES)}, bus)
        self._publish_state()
        self.get_logger().info('station sequencer ready (%s pairing, search grid %d x %d '
                               'at %.3g mm/s)' % ('index' if self.lockstep else
                                                  'latest readings', self.seq.grid_n,
                                                  self.seq.grid_n, self.seq.search_speed * 1e3))

    # -- inputs ---------------------------------------------------------------------
    def _on_position(self, i, msg):
        x = msg.position[0] if len(msg.position) else math.nan
        if self.lockstep:
            self.q[i].append(x)
            self._pair()
            return
        self.latest[i] = x
        if i == 0:
            p = self.q_p[-1] if self.q_p else None
            self.q_p = []
            self._step(stamp_to_s(msg.header.stamp), list(self.latest), p)

    def _on_power(self, msg):
        self.q_p.append(float(msg.data))
        if self.lockstep:
            self._pair()

    def _pair(self):
        q = self.q
        while all(q) and self.q_p:
            self._step(self.n * self.period_s, [a.pop(0) for a in q], self.q_p.pop(0))
        while len(q[0]) > POWER_QUEUE_LIMIT and all(q):
            self._step(self.n * self.period_s, [a.pop(0) for a in q], None)

    # -- the step -------------------------------------------------------------------
    def _step(self, t, pos, p):
        ok = all(v is not None and math.isfinite(v) for v in pos)
        r = self.seq.update(t, pos if ok else None, p)
        self.n += 1
        self.t_last = t
        for pub, v in zip(self.pub_sp, r):
            pub.publish(Float64(data=float(v)))
        self._publish_state()

    def _publish_state(self):
        s = self.seq.status()
        s.update(sample=self.n, align_sample=self.align_sample, sample_time_s=self.t_last)
        self._publish_status(s, sample=self.n)

    def sent_counts(self):
        """Return published message counts per topic."""
        out = {a + '/setpoint': self.n for a in AXES}
        out['alignment_state'] = self.n_state
        return out


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(StationSequencerNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
