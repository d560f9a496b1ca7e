# SPDX-License-Identifier: Apache-2.0
"""
``alignment_sequencer``: the setpoint source that finds, peaks, tracks and switches light.

Wraps :class:`fiber_align.alignment.sequencer.Sequencer` (one ``update`` per displacement
sample). Topics and services (relative names, SI units):

- sub ``displacement`` (sensor_msgs/JointState, position[0] in m, stamp = t_k) and
  ``optical_power`` (std_msgs/Float64, W).
- pub ``setpoint`` (std_msgs/Float64, m): exactly one per displacement sample.
- pub ``alignment_state`` (std_msgs/String, JSON: state, fault_reason,
  aligned_position_m, threshold_w, peak_samples, hold_reason), latched, on every change.
- ``/diagnostics``: OK while IDLE, SEARCHING, PEAKING, TRACKING, RELEASING; WARN with
  the reason in HELD (the driver holds its output); ERROR with the reason in FAULT.
- srv ``align``, ``release`` (std_srvs/Trigger); ``switch`` (std_srvs/SetBool: true goes
  to the last aligned position and re-peaks, false parks at 0 m).
- the driver's state (``_sequencer_node``): its latched ``drive_held`` (std_msgs/Bool),
  ``actuator_driver/transition_event`` (lifecycle_msgs/TransitionEvent) and its status
  on ``/diagnostics`` go to the core (:mod:`fiber_align.alignment.driver_state`): a
  driver that stops driving (tripped, disabled, inactive, unconfigured, its device or
  its process lost) puts an active state in HELD at once (the setpoint held, a WARN
  on ``/diagnostics`` with the reason), which re-peaks once the driver drives again and
  FAULTs after ``driver_down_timeout_s``; ``align`` and ``switch`` true are refused
  (success false, the reason and what to do) while it is down.

``sensorless`` (graph-wide, the hardware graph: no ``displacement``): one ``update`` per
``optical_power`` reading, against the commanded displacement: the newest ``reference``
(std_msgs/Float64, m, the setpoint the compensator accepted and positions by its inverse
PI feedforward alone), at the wall time since the first reading, each gap counted as at
most :data:`MAX_GAP_PERIODS` control periods (a stalled period then moves the search by
its usual step, not by a jump).

Pairing: ``lockstep`` pairs the i-th displacement with the i-th optical power (the plant
publishes both for every sample); if the plant publishes no power, a displacement waits
at most ``power_queue_limit`` samples and is then processed without power (which the core
reports as "sensor silent" once active). ``realtime`` uses the power readings received
since the previous displacement (the latest one), or none.
"""

import math
import sys
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from fiber_align.alignment import sequencer as sq
from fiber_align.graph.registry import NODES
from fiber_align.nodes._sequencer_node import SequencerNode
from fiber_align.nodes.ros.bus import Pub, sender_of, slack_of, stamp_to_s, subscription
from fiber_align.nodes.ros.diagnostics import Health
from fiber_align.nodes.ros.params import declare_graph_values, declare_si, node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import (REALTIME_QOS, REFERENCE_LATCHED_QOS, sample_pub_qos,
                                       sample_qos)
from fiber_align.nodes.ros.runtime import run_node

#: the registry's entry of this node: its name and params files
SPEC = NODES['alignment_sequencer']
POWER_QUEUE_LIMIT = 5
#: Sensorless: the most control periods one reading advances the sequencer's clock by.
MAX_GAP_PERIODS = 1.5


class AlignmentSequencerNode(SequencerNode, Node):
    """Transport, services and health around the pure :class:`~sq.Sequencer`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare the parameters (defaults from config/), build the core, wire topics.

        :param bus: the :class:`~fiber_align.nodes.ros.bus.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'sensorless',
                                 'rate_hz', *PRIORITY)
        self.lockstep, diag = g['sync_mode'] == 'lockstep', g['diagnostics_period_s']
        core = {}
        for name in sq.KEYS:
            if name in d:
                core[name] = declare_si(self, d, name, 'sequencer')
        self.seq = sq.Sequencer({k: v for k, v in core.items()})
        self.pub_sp = Pub(self, Float64, 'setpoint', sample_pub_qos(self.lockstep), bus)
        qos = sample_qos(self.lockstep)
        self.sensorless = bool(g['sensorless'])
        self.max_gap_s = MAX_GAP_PERIODS / float(g['rate_hz'])
        self.y_ref = None               # sensorless: the newest reference (m)
        self._t = self._wall = None     # sensorless: control clock (s) and its wall time
        if self.sensorless:
            subscription(self, Float64, 'reference', self._on_reference,
                         REFERENCE_LATCHED_QOS, bus)
            subscription(self, Float64, 'optical_power', self._on_reading,
                         REALTIME_QOS, bus)
        else:
            subscription(self, JointState, 'displacement', self._on_disp, qos, bus)
            subscription(self, Float64, 'optical_power', self._on_power, qos, bus)
        self._serve()
        self.health = Health(self, diag, slack=slack_of(bus), sender=sender_of(bus))
        self.y_q = []
        self.p_q = []
        self.n_sp = 0
        self.t_last = None              # sample time (s) of the last sample stepped
        self._watch_drivers({'actuator_driver': ''}, bus)
        self._publish_state()
        self.get_logger().info('sequencer ready (%s pairing)'
                               % ('index' if self.lockstep else 'latest power'))

    # -- inputs ---------------------------------------------------------------------
    def _on_power(self, msg):
        self.p_q.append(float(msg.data))
        if self.lockstep:
            self._pair()
        else:
            del self.p_q[:-1]

    def _on_disp(self, msg):
        y = msg.position[0] if len(msg.position) else math.nan
        t = stamp_to_s(msg.header.stamp)
        if self.lockstep:
            self.y_q.append((t, y))
            self._pair()
        else:
            p = self.p_q.pop() if self.p_q else None
            self.p_q = []
            self._step(t, y, p)

    def _on_reference(self, msg):
        self.y_ref = float(msg.data)

    def _on_reading(self, msg):
        """Sensorless: one step per reading (W) at the commanded displacement (m)."""
        w = time.monotonic()
        gap = 0.0 if self._t is None else min(max(w - self._wall, 0.0), self.max_gap_s)
        self._t = gap if self._t is None else self._t + gap
        self._wall = w
        y = self.y_ref if self.y_ref is not None else self.seq.status()['setpoint_m']
        self._step(self._t, y, float(msg.data))

    def _pair(self):
        while self.y_q and self.p_q:
            t, y = self.y_q.pop(0)
            self._step(t, y, self.p_q.pop(0))
        while len(self.y_q) > POWER_QUEUE_LIMIT:
            t, y = self.y_q.pop(0)
            self._step(t, y, None)

    # -- the step -------------------------------------------------------------------
    def _step(self, t, y, p):
        y = None if not math.isfinite(y) else y
        self.t_last = t
        r = self.seq.update(t, y, p)
        self.pub_sp.publish(Float64(data=float(r)))
        self.n_sp += 1
        self._publish_state()

    def _publish_state(self):
        s = self.seq.status()
        # the sample time (s, its stamp) of the last sample stepped: an observer lagging
        # behind a lockstep graph indexes the state by it, not by its own count
        s['sample_time_s'] = self.t_last
        self._publish_status(s, aligned_position_m=s['aligned_position_m'])

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'setpoint': self.n_sp, 'alignment_state': self.n_state}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(AlignmentSequencerNode, SPEC.node, args,
                    realtime=lambda node: not node.lockstep)


if __name__ == '__main__':
    sys.exit(main())
