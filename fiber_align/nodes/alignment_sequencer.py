# SPDX-License-Identifier: Apache-2.0
"""
``alignment_sequencer``: the setpoint source that finds, peaks, tracks and switches light.

One executable for every machine, chosen by its read-only parameter ``machine`` (the
differences are data: :mod:`fiber_align.graph.machines`). SI units; ``<a>/`` an axis:

- sub ``<a>/displacement`` (sensor_msgs/JointState, m), ``optical_power`` (Float64, W;
  the array's also ``optical_power_n``); pub ``<a>/setpoint`` (Float64, m) per update;
- pub ``alignment_state`` (std_msgs/String, JSON), latched, on every change of state or
  fault; the core's events logged; ``/diagnostics``: OK, WARN in HELD, ERROR in FAULT;
- srv ``align``, ``release`` (std_srvs/Trigger), ``switch`` (std_srvs/SetBool);
- the drivers' ``<a>/drive_held``, ``<a>/actuator_driver/transition_event`` and
  ``/diagnostics`` go to the core (:mod:`fiber_align.alignment.driver_state`).

Pairing (lockstep: by index; realtime: the latest; sensorless: one step per set of the
meters' readings) and the rest: docs/ros_interface.md, docs/array.md.
"""

import json
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import TransitionEvent
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, String
from std_srvs.srv import SetBool, Trigger

from fiber_align.alignment.states import FAULT, HELD
from fiber_align.config import load_params
from fiber_align.control.trajectory import stamp_to_s
from fiber_align.graph.machines import CONFIG_FILES, MACHINES
from fiber_align.hardware.pm100_session import ReadingSets
from fiber_align.nodes.ros.bus import local_too, Pub, sender_of, slack_of, subscription
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK, WARN
from fiber_align.nodes.ros.params import declare, declare_graph_values, declare_si
from fiber_align.nodes.ros.params import declare_part, node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import (DIAG_QOS, LATCHED_QOS, REALTIME_QOS,
                                       REFERENCE_LATCHED_QOS, sample_pub_qos, sample_qos,
                                       STATE_QOS, TRANSITION_EVENT_QOS)
from fiber_align.nodes.ros.runtime import run_node

POWER_QUEUE_LIMIT = 5
#: s from a driver's last ``drive_held`` writer unmatched to "gone".
GONE_GRACE_S = 0.05


class AlignmentSequencerNode(Node):
    """Transport, services, drivers' state and health around a machine's pure core."""

    NAME = 'alignment_sequencer'

    def __init__(self, bus=None, **kwargs):
        """Declare the parameters, build the core, wire every axis (``bus``: a LocalBus)."""
        super().__init__(self.NAME, **kwargs)
        d = node_defaults(self.get_name(), CONFIG_FILES)
        self.machine = declare(self, d, 'machine', 'the machine this sequencer aligns',
                               read_only=True, choices=tuple(MACHINES))
        m = self.m = MACHINES[self.machine]
        g = declare_graph_values(self, d, 'sync_mode', 'diagnostics_period_s', 'sensorless',
                                 'rate_hz', 'realtime_setpoint_rate_m_per_s', *PRIORITY)
        self.lockstep, self.period_s = g['sync_mode'] == 'lockstep', 1.0 / g['rate_hz']
        keys = load_params(m.module.CONFIG_FILE, m.module.CONFIG_NODE)
        core = {k: declare_si(self, dict(keys, **d), k, 'sequencer') for k in keys}
        # realtime: the search walks no faster than the loop's path follows a setpoint
        self.seq = m.build(core, self.period_s, None if self.lockstep
                           else g['realtime_setpoint_rate_m_per_s'])
        pre = self.pre = [a + '/' if a else '' for a in m.axes]
        self.pub_sp = [Pub(self, Float64, p + 'setpoint', sample_pub_qos(self.lockstep), bus)
                       for p in pre]
        # sensorless: the newest references (m), the meters' readings in sets and the clock
        self.ref, self.sets = [None] * len(pre), ReadingSets(len(m.powers), self.period_s)
        self.sensorless, qos = bool(g['sensorless']), sample_qos(self.lockstep)
        for i, p in enumerate(pre):
            if self.sensorless:
                subscription(self, Float64, p + 'reference', lambda msg, i=i:
                             self.ref.__setitem__(i, float(msg.data)),
                             REFERENCE_LATCHED_QOS, bus)
            else:
                subscription(self, JointState, p + 'displacement',
                             lambda msg, i=i: self._on_position(i, msg), qos, bus)
        for j, topic in enumerate(m.powers):        # paired by index, as the positions
            subscription(self, Float64, topic, lambda msg, j=j: (
                self._on_power, self._on_reading)[self.sensorless](j, msg),
                REALTIME_QOS if self.sensorless else qos, bus)
        self.pub_state, self.n_state, self._last, self.part = self.create_publisher(
            String, 'alignment_state', STATE_QOS), 0, None, declare_part(self, d)
        self._state_out = local_too(self.pub_state, bus, self, 'alignment_state')
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, DIAG_QOS)
        self.create_service(Trigger, 'align', lambda q, r: self._answer(r, self.seq.align(), 1))
        self.create_service(Trigger, 'release', lambda q, r: self._answer(r, self.seq.release()))
        self.create_service(SetBool, 'switch', lambda q, r: self._answer(
            r, self.seq.switch(bool(q.data))))
        self.health = Health(self, g['diagnostics_period_s'], slack=slack_of(bus),
                             sender=sender_of(bus))
        self.q, self.q_p = [[] for _ in pre], [[] for _ in m.powers]    # (s, m) and W
        self.latest = [None] * len(pre)     # realtime: the newest reading of each axis (m)
        self.n, self.align_sample, self.t_last, self.p_last, self.p_peak = 0, *[None] * 4
        self._watch_drivers(bus)
        self._publish_state()
        self.get_logger().info('sequencer ready: machine %s, %s' % (self.machine, g['sync_mode']))

    def _watch_drivers(self, bus):
        ns, amp = self.get_namespace().rstrip('/'), self.m.amplifier if self.sensorless else ''
        self._driver_diag = {}
        for p, a in zip(self.pre, self.m.axes):
            name, topic = self.m.driver(a), p + 'drive_held'
            self._driver_diag['%s/%s' % (ns, name)] = name
            if amp:     # the hardware rig: one amplifier reports each axis by name
                self._driver_diag['%s/%s/%s' % (ns, amp, a)] = name

            def held(msg, n=name):
                self._driver_news(self.seq.driver_held(bool(msg.data), n))

            def matched(info, n=name, t=topic):     # the last writer left: gone soon?
                if info.current_count == 0 and info.current_count_change < 0:
                    self._gone_later(n, self.resolve_topic_name(t))
            if bus is not None and bus.local(self, topic):
                subscription(self, Bool, topic, held, LATCHED_QOS, bus)   # same process
            else:
                self.create_subscription(Bool, topic, held, LATCHED_QOS, event_callbacks=(
                    SubscriptionEventCallbacks(matched=matched)))
            self.create_subscription(TransitionEvent, (amp or name) + '/transition_event',
                                     lambda msg, n=name: self._driver_news(
                                         self.seq.driver_lifecycle(msg.goal_state.label, n)),
                                     TRANSITION_EVENT_QOS)

    def _gone_later(self, name, topic):
        """Call ``name`` gone after :data:`GONE_GRACE_S` if ``topic`` still has no writer."""
        box = []

        def fire():
            self.destroy_timer(box[0])
            if self.count_publishers(topic) == 0:
                self._driver_news(self.seq.driver_gone(name))
        box.append(self.create_timer(GONE_GRACE_S, fire,
                                     clock=Clock(clock_type=ClockType.STEADY_TIME)))

    def _driver_news(self, acted):
        return acted and self._publish_state()

    def _on_diag(self, msg):
        for s in msg.status:
            if s.name in self._driver_diag:
                level = s.level[0] if isinstance(s.level, (bytes, bytearray)) else int(s.level)
                self._driver_news(self.seq.driver_diagnostics(level < ERROR,
                                                              self._driver_diag[s.name]))

    def _answer(self, response, result, align=False):
        if align and result[0]:     # the index of the update the command acted before
            self.align_sample = self.n
        response.success, response.message = bool(result[0]), str(result[1])
        self._publish_state()
        return response

    def _on_position(self, i, msg):
        x, t = msg.position[0] if len(msg.position) else math.nan, stamp_to_s(msg.header.stamp)
        if self.lockstep:
            self.q[i].append((t, x))
            self._pair()
            return
        self.latest[i] = x
        if i == 0:
            p, self.q_p = [(q or [None])[-1] for q in self.q_p], [[] for _ in self.q_p]
            self._step(t, list(self.latest), p)

    def _on_power(self, j, msg):
        self.q_p[j].append(float(msg.data))
        if self.lockstep:
            self._pair()
        else:
            del self.q_p[j][:-1]

    def _on_reading(self, j, msg):
        """Sensorless: one step per set of readings (W) at the commanded positions (m)."""
        got = self.sets.add(j, msg.data, time.monotonic())
        if got is not None:
            self._step(got[0], [s if r is None else r for r, s in
                                zip(self.ref, self.m.setpoints(self.seq))], got[1])

    def _pair(self):
        while all(self.q) and (all(self.q_p) or len(self.q[0]) > POWER_QUEUE_LIMIT):
            got = [a.pop(0) for a in self.q]        # (s, m); a power, or None past the limit
            self._step(self.n * self.period_s if self.m.counted else got[0][0],
                       [x for _, x in got], [w.pop(0) if w else None for w in self.q_p])

    def _step(self, t, pos, p):
        r = self.m.update(self.seq, t, [v if v is not None and math.isfinite(v) else None
                                        for v in pos], p)
        self.n, self.t_last, self.p_last = self.n + 1, t, (p or [None])[0]   # W, channel 1
        if self.p_last is not None and math.isfinite(self.p_last):   # the status's peak
            self.p_peak = max(self.p_last, self.p_peak or self.p_last)
        for pub, v in zip(self.pub_sp, r):
            pub.publish(Float64(data=float(v)))
        self._publish_state()

    def _publish_state(self):
        """Publish the status when its state or fault changed; health and log too."""
        for _, state, text in self.seq.events:  # the core's findings: patterns, first light
            if text and state != FAULT:
                self.get_logger().info(text)
        self.seq.events.clear()                 # (a week of alignments: not kept)
        if (self.seq.state, self.seq.fault_reason) == self._last:    # most periods
            return
        s = self.part(self.seq.status(), self.p_last, self.p_peak)    # the catalogue's
        # the time (s) of the last update: a lagging observer indexes the state by it
        s['sample_time_s'] = self.t_last
        values = {k: s[k] for k in self.m.values}
        if self.m.counted:
            s.update(sample=self.n, align_sample=self.align_sample)
            values['sample'] = self.n
        self._last, self.p_peak = (s['state'], s['fault_reason']), None
        self._state_out(String(data=json.dumps(s)))
        self.n_state += 1
        log = self.get_logger()
        level, text, say = (ERROR, 'FAULT: %s' % s['fault_reason'], log.error) \
            if s['state'] == FAULT else (WARN, 'HELD: %s' % s.get('hold_reason', ''),
                                         log.warning) if s['state'] == HELD else (
            OK, s['state'], lambda text: log.info('state ' + text))
        self.health.summary(level, text)
        say(text)
        self.health.set_values(state=s['state'], fault_reason=s['fault_reason'],
                               peak_samples=s['peak_samples'], **values)

    def sent_counts(self):
        """Return published message counts per topic."""
        return dict({p + 'setpoint': self.n for p in self.pre}, alignment_state=self.n_state)


#: The nodes of the other machines as ``control_graph`` hosts them (their ``NAME``).
RigSequencerNode, StationSequencerNode, ArraySequencerNode = (
    type(c, (AlignmentSequencerNode,), dict(NAME=n, __doc__='The node ``%s``.' % n))
    for c, n in (('RigSequencerNode', 'alignment_sequencer_2d'),
                 ('StationSequencerNode', 'station_sequencer'),
                 ('ArraySequencerNode', 'array_sequencer')))


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(AlignmentSequencerNode, AlignmentSequencerNode.NAME, args,
                    realtime=lambda node: not node.lockstep)


if __name__ == '__main__':
    sys.exit(main())
