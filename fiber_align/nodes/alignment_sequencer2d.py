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
- ``/diagnostics``: OK in IDLE, SEARCHING, PEAKING, TRACKING, RELEASING; WARN with the
  reason in HELD; ERROR in FAULT.
- the drivers' state (``_sequencer_node``): ``x/drive_held``, ``y/drive_held``
  (std_msgs/Bool, latched), ``x/actuator_driver/transition_event`` and
  ``y/actuator_driver/transition_event`` (lifecycle_msgs/TransitionEvent) and their
  statuses on ``/diagnostics`` go to the core (:mod:`fiber_align.alignment.
  driver_state`): a driver that stops driving puts an active state in HELD at once
  (the setpoints held, the reason said; a new search or a re-peak once it drives
  again, FAULT after ``driver_down_timeout_s``); ``align`` and ``switch`` true are
  refused while one is down. On the
  hardware rig the axis statuses ``mdt693b_driver/x`` and ``mdt693b_driver/y`` stand for
  the drivers' on ``/diagnostics``.
- srv ``align``, ``release`` (std_srvs/Trigger); ``switch`` (std_srvs/SetBool).

``sensorless`` (graph-wide, the hardware rig: no ``displacement``): one ``update`` per
``optical_power`` reading against the commanded positions, the newest ``x/reference``
and ``y/reference`` (m, the setpoints each compensator accepted and positions by its
inverse PI feedforward alone), at the wall time since the first reading, each gap
counted as at most ``MAX_GAP_PERIODS`` control periods (as the 1-D sequencer).

Pairing: ``lockstep`` pairs the i-th x, y and power and calls ``update`` with
``t_i = i / rate_hz`` (the offline bench's time, bit for bit: the plants stamp
the same ``i T`` to the ns); a command (service) acts before the next update, whose index
``alignment_state`` reports as ``sample``. If no power arrives, positions wait at most
``power_queue_limit`` samples and are then processed without power (the core reports
"sensor silent"). ``realtime`` steps on every x sample (its stamp is t) with the latest
y and the power received since the previous step, or none.
"""

import math
import sys
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from fiber_align.alignment import sequencer2d as s2d
from fiber_align.graph.registry import NODES
from fiber_align.graph.hardware_rig import AMPLIFIER
from fiber_align.nodes._sequencer_node import SequencerNode
from fiber_align.nodes.alignment_sequencer import MAX_GAP_PERIODS, POWER_QUEUE_LIMIT
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, stamp_to_s, subscription
from fiber_align.nodes.ros.diagnostics import Health
from fiber_align.nodes.ros.params import declare_graph_values, node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import (REALTIME_QOS, REFERENCE_LATCHED_QOS, sample_pub_qos,
                                       sample_qos)
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['alignment_sequencer_2d']
AXES = ('x', 'y')


class AlignmentSequencer2DNode(SequencerNode, Node):
    """Transport, services and health around the pure :class:`~s2d.Sequencer2D`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare every key of ``sequencer2d.yaml`` (read-only), build the core, wire both axes.

        :param bus: the ``LocalBus`` of the rig's composed process, or ``None``.
        """
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'rate_hz',
                                 'sensorless', 'realtime_setpoint_rate_m_per_s', *PRIORITY)
        self.lockstep, diag = g['sync_mode'] == 'lockstep', g['diagnostics_period_s']
        core = self._declare_core(d, s2d.CONFIG_FILE, s2d.CONFIG_NODE)
        self.period_s = 1.0 / float(g['rate_hz'])
        # realtime: the search walks no faster than the loop's path follows a setpoint
        self.seq = s2d.Sequencer2D(core, period_s=self.period_s, path_rate_m_per_s=None
                                   if self.lockstep else g['realtime_setpoint_rate_m_per_s'])
        self.pub_sp = [Pub(self, Float64, a + '/setpoint', sample_pub_qos(self.lockstep), bus)
                       for a in AXES]
        qos = sample_qos(self.lockstep)
        self.sensorless = bool(g['sensorless'])
        self.max_gap_s = MAX_GAP_PERIODS * self.period_s
        self.ref = {a: None for a in AXES}      # sensorless: the newest references (m)
        self._t = self._wall = None     # sensorless: control clock (s) and its wall time
        if self.sensorless:
            for a in AXES:
                subscription(self, Float64, a + '/reference',
                             lambda msg, a=a: self._on_reference(a, msg),
                             REFERENCE_LATCHED_QOS, bus)
            subscription(self, Float64, 'optical_power', self._on_reading, REALTIME_QOS, bus)
        else:
            subscription(self, JointState, 'x/displacement', self._on_x, qos, bus)
            subscription(self, JointState, 'y/displacement', self._on_y, qos, bus)
            subscription(self, Float64, 'optical_power', self._on_power, qos, bus)
        self._serve()
        self.health = Health(self, diag, slack=slack_of(bus), sender=sender_of(bus))
        self.q = {'x': [], 'y': [], 'p': []}
        self.y_latest = None
        self.n = 0                      # updates done = index of the next sample
        self.align_sample = None
        self.t_last = None              # time (s) of the last update
        # the hardware rig (sensorless): one amplifier node's transitions are both axes'
        self._watch_drivers({name: a + '/' for name, a in zip(s2d.DRIVERS, AXES)}, bus,
                            {n: AMPLIFIER for n in s2d.DRIVERS} if self.sensorless else None)
        ns = self.get_namespace().rstrip('/')
        # the hardware rig: one mdt693b_driver reports each axis under its own status name
        self._driver_diag.update({'%s/mdt693b_driver/%s' % (ns, a): name
                                  for name, a in zip(s2d.DRIVERS, AXES)})
        self._publish_state()
        self.get_logger().info('2-D sequencer ready (%s pairing, search at %.3g mm/s)'
                               % ('index' if self.lockstep else 'latest y and power',
                                  self.seq.search_speed * 1e3))

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
        self._step(stamp_to_s(msg.header.stamp), self._position(msg), self.y_latest, p)

    def _on_y(self, msg):
        if self.lockstep:
            self.q['y'].append(self._position(msg))
            self._pair()
        else:
            self.y_latest = self._position(msg)

    def _on_reference(self, axis, msg):
        self.ref[axis] = float(msg.data)

    def _on_reading(self, msg):
        """Sensorless: one step per reading (W) at the commanded positions (m)."""
        w = time.monotonic()
        gap = 0.0 if self._t is None else min(max(w - self._wall, 0.0), self.max_gap_s)
        self._t = gap if self._t is None else self._t + gap
        self._wall = w
        s = self.seq.status()
        x = self.ref['x'] if self.ref['x'] is not None else s['setpoint_x_m']
        y = self.ref['y'] if self.ref['y'] is not None else s['setpoint_y_m']
        self._step(self._t, x, y, float(msg.data))

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

    # -- the step -------------------------------------------------------------------
    def _step(self, t, x, y, p):
        def ok(v):
            return v if v is not None and math.isfinite(v) else None
        rx, ry = self.seq.update(t, ok(x), ok(y), p)
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

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'x/setpoint': self.n, 'y/setpoint': self.n, 'alignment_state': self.n_state}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(AlignmentSequencer2DNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
