# SPDX-License-Identifier: Apache-2.0
"""
The flight recorder of ``bag_recorder``: its parameters, triggers, service and topic.

Shaped like control_toolbox's ``PidROS``: :class:`FlightROS` owns the pure core
(:class:`~fiber_align.analysis.bag.flight.FlightRecorder`, :class:`~fiber_align.analysis.
bag.flight.Triggers`) and takes the node's interfaces. Parameters (``config/recorder.yaml``,
ranges ``graph.ranges.RECORDER_RANGES``): ``snapshots`` (folder; ``''``: off),
``snapshot_before_s``, ``snapshot_after_s`` (s), ``snapshot_max_bytes`` (all rings, split
evenly over the recorded topics). Triggers: ``alignment_state`` (FAULT, HELD),
``/diagnostics`` (a ``watchdog_count`` rising, a plant's cycle WARN),
``actuator_driver/transition_event`` (deactivated) and the service ``~/snapshot``
(std_srvs/Trigger). Each bag written is announced on ``snapshot_written`` (std_msgs/String,
its path; latched) for the run catalogue. The bags are written by the core's worker
thread, never by a callback (a composed recorder's run on a control thread).
"""

from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import TransitionEvent
from std_msgs.msg import String
from std_srvs.srv import Trigger

from fiber_align.analysis.bag.flight import FlightRecorder, Triggers
from fiber_align.graph.ranges import RECORDER_RANGES
from fiber_align.nodes.ros.params import declare_row
from fiber_align.nodes.ros.qos import DIAG_QOS, STATE_QOS, TRANSITION_EVENT_QOS

#: the parameters, in ``config/recorder.yaml``
KEYS = ('snapshots', 'snapshot_before_s', 'snapshot_after_s', 'snapshot_max_bytes')
#: the lifecycle node whose deactivation is a trigger (relative to the recorder)
DRIVER = 'actuator_driver'


class FlightROS:
    """
    The flight recorder on a node: declare, subscribe, serve; keep and write in the core.

    :param node: the recorder node; :param defaults: its params files' values.
    :param n_topics: the topics it records (the memory bound is split over them).
    :param storage: the snapshots' bag storage.
    """

    def __init__(self, node, defaults, n_topics, storage):
        """Declare the parameters; with a folder, start the triggers and the service."""
        p = {k: declare_row(node, defaults, RECORDER_RANGES, k, True) for k in KEYS}
        self.node, self.core = node, None
        if not p['snapshots']:
            return
        self.core = FlightRecorder(p['snapshots'], p['snapshot_before_s'],
                                   p['snapshot_after_s'], p['snapshot_max_bytes'], n_topics,
                                   storage, on_written=self._written)
        self.triggers = Triggers()
        self.pub = node.create_publisher(String, 'snapshot_written', STATE_QOS)
        node.create_service(Trigger, '~/snapshot', self._on_service)
        tr = self.triggers
        node.create_subscription(String, 'alignment_state',
                                 lambda m: self.fire(tr.on_state(m.data)), STATE_QOS)
        node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: [
            self.fire(tr.on_diagnostic(s)) for s in m.status], DIAG_QOS)
        node.create_subscription(TransitionEvent, DRIVER + '/transition_event', lambda m: (
            self.fire(tr.on_transition(DRIVER, m.start_state.label, m.goal_state.label))),
            TRANSITION_EVENT_QOS)
        node.get_logger().info(
            'flight recorder: the last %.1f s of every topic in memory (at most %d bytes, '
            '%d a topic); snapshots of [t - %.1f s, t + %.1f s] into %s' % (
                self.core.horizon_s, self.core.max_bytes, self.core.topic_bytes,
                self.core.before_s, self.core.after_s, self.core.folder))

    def keeper(self, topic, msgtype):
        """Return the append of ``topic``'s ring ``(t_ns, CDR bytes)``, or None (off)."""
        return self.core.ring(topic, msgtype).append if self.core is not None else None

    def fire(self, reason):
        """Ask for a snapshot for ``reason`` (None: nothing); return it or None."""
        if not reason or self.core is None:
            return None
        snap = self.core.trigger(reason)
        log = self.node.get_logger()
        if snap is None:
            log.info('snapshot trigger %r inside the pending window: counted' % reason)
        else:
            log.warning('snapshot %r: %s in %.1f s' % (reason, snap.path,
                                                       self.core.after_s))
        return snap

    def _on_service(self, request, response):
        snap = self.fire('service') if self.core is not None else None
        response.success = snap is not None
        response.message = snap.path if snap is not None else (
            'snapshots are off' if self.core is None else 'inside the window of %s: counted'
            % self.core.snapshots[-1].path)
        return response

    def _written(self, snap):
        """Announce a written snapshot (the core's worker thread)."""
        log = self.node.get_logger()
        if snap.error:
            log.error('snapshot %s not written: %s' % (snap.path, snap.error))
            return
        log.info('snapshot %s written: %s' % (snap.path, ', '.join(
            '%s %d' % kv for kv in sorted(snap.counts.items()))))
        self.pub.publish(String(data=snap.path))

    def values(self):
        """Return the core's figures for ``/diagnostics`` (none when off)."""
        return self.core.state() if self.core is not None else {}

    def close(self):
        """Write what is pending with what the rings hold (bounded); stop the worker."""
        if self.core is not None:
            self.core.close()
