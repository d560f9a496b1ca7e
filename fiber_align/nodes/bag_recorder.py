# SPDX-License-Identifier: Apache-2.0
"""
``bag_recorder``: record the graph's topics into a rosbag2 (version 9) bag with rosbags.

Stands in for rosbag2's recorder (``ros2 bag record``), which a pip install of ROS 2 lacks.
Parameters: ``config/recorder.yaml``. A topic is subscribed raw (the CDR bytes written as
received, stamped with the wall-clock receive time in ns) once a publisher shows its type,
with the publishers' QoS; in ``control_graph`` a topic of the process is taken from its
bus (:class:`fiber_align.nodes.ros.cdr.BusTopic`), not through DDS. The writing, a full
disk and the counts: :class:`fiber_align.analysis.bag.sink.Sink`; lost messages,
incompatible QoS and ``fiber-align bag-repair``: docs/ros_interface.md. ``record`` false:
no bag; the flight recorder (:mod:`fiber_align.nodes.ros.flight`) keeps the last seconds
of every topic and writes a snapshot bag on a trigger either way (docs/records.md).
"""

from datetime import datetime
import sys
import threading
import time

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node

from fiber_align import lifeline
from fiber_align.analysis.bag.sink import Sink
from fiber_align.analysis.recording import STOPPED_EARLY
from fiber_align.graph.ranges import RECORDER_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes._msgtypes import message_class
from fiber_align.nodes.ros.bus import sender_of, slack_of
from fiber_align.nodes.ros.cdr import BusTopic
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK, WARN
from fiber_align.nodes.ros.flight import FlightROS
from fiber_align.nodes.ros.params import declare, declare_graph_values, declare_row
from fiber_align.nodes.ros.params import node_defaults, PRIORITY
from fiber_align.nodes.ros.qos import reader_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.nodes.ros.teardown import spin_until_quiet

#: the registry's entry of this node: its name and params files
SPEC = NODES['bag_recorder']


def _default_output():
    return 'fiber_align_' + datetime.now().strftime('%Y%m%d_%H%M%S')


class BagRecorder(Node):
    """Subscribe raw to the requested topics as they appear and write them to a bag."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare the parameters, open the bag and start discovery.

        :param bus: the process's :class:`~fiber_align.nodes.ros.bus.LocalBus`
            (composed): the topics its nodes publish are recorded in-process.
        """
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        ro = True
        self.record = declare(self, d, 'record', 'write the full bag (bool; false: '
                              'snapshots only)', read_only=ro)
        self.output = declare(self, d, 'output', 'bag directory to create (must not '
                              'exist); empty: fiber_align_<date_time>', read_only=ro) \
            or _default_output()
        storage = declare(self, d, 'storage', 'bag storage', read_only=ro,
                          choices=('mcap', 'sqlite3'))
        declare(self, d, 'topics', 'topics to record (relative names resolve in the '
                'namespace)', read_only=ro)
        period = declare_row(self, d, RECORDER_RANGES, 'discovery_period_s', ro)
        self.depth = declare_row(self, d, RECORDER_RANGES, 'queue_depth', ro)
        self.counts_file = declare(self, d, 'counts_file', 'write recorder_events.json '
                                   'next to the bag (bool)', read_only=ro)
        declare_row(self, d, RECORDER_RANGES, 'flush_period_s', ro)
        declare_graph_values(self, d, 'diagnostics_period_s', *PRIORITY)
        gp = self.get_parameter
        self.wanted = [self.resolve_topic_name(t) for t in gp('topics').value]
        self.flight = FlightROS(self, d, len(self.wanted), storage)
        if not self.record:
            self.output = ''
        self.sink = Sink.open(self.output, storage, self.flight.keeper,
                              gp('flush_period_s').value)
        self.bag, self.typestore = self.sink.bag, self.sink.typestore
        self.counts = self.sink.counts
        self.closed, self.finisher = False, None
        self.subs = {}
        self.lost = self.incompatible = 0
        self.bus = bus
        self.local = {}         # topic -> BusTopic: recorded in-process
        if bus is not None:
            for topic in self.wanted:
                if topic in bus.topics:
                    self.counts[topic] = 0      # a latched message arrives at once
                    self.local[topic] = BusTopic(bus, topic, self.sink, self.stopped_early,
                                                 self.get_logger())
            # the control thread's slack runs the discovery and the writes
            self.timer = self.create_timer(period, lambda: bus.slack.submit(self.discover))
        else:
            self.timer = self.create_timer(period, self.discover)
            if self.sink.flush_s > 0:
                self.create_timer(self.sink.flush_s, self.flush)
        self.health = Health(self, float(gp('diagnostics_period_s').value),
                             update=self._diag_values,
                             slack=slack_of(bus), sender=sender_of(bus))
        self.get_logger().info('recording %s into %s (%s)' % (
            ', '.join(self.wanted), self.output or 'no bag', storage))
        self.discover()

    def discover(self):
        """
        Subscribe to every wanted topic whose type is now known.

        A publisher count per topic still missing first (one cheap graph query each,
        which is all a look costs while, say, ``/clock`` of a realtime graph never
        comes); the whole topic list only when one has a publisher now.
        """
        if self.closed:
            return
        new = [t for t in self.wanted if t not in self.subs and t not in self.local
               and self.count_publishers(t)]
        if not new:
            return
        types = dict(self.get_topic_names_and_types())
        for topic in new:
            if topic not in types:
                continue
            msgtype = types[topic][0]
            if not self.get_publishers_info_by_topic(topic):
                continue
            try:
                cls = message_class(msgtype)
                write = self.sink.put(topic, msgtype)
            except Exception as exc:  # noqa: BLE001 - unknown type: skip it, say so
                self.get_logger().warning('cannot record %s (%s): %s' % (topic, msgtype, exc))
                self.subs[topic] = None
                continue
            qos = reader_qos(self.get_publishers_info_by_topic(topic), self.depth)
            self.subs[topic] = self.create_subscription(
                cls, topic, self._callback(write), qos, raw=True,
                event_callbacks=self._events(topic))
            self.get_logger().info('subscribed to %s (%s)' % (topic, msgtype))

    def _callback(self, write):
        def cb(data):
            if not self.closed and not write(time.time_ns(), data):
                self.stopped_early()
        return cb

    def stopped_early(self):
        """Stop recording after a failed write (a full disk): one line; the graph runs on."""
        if self.closed:
            return
        self.closed = True              # no more writes; _finish closes the bag
        self.get_logger().error(self.bag.stopped)
        self._leave()
        if self.bus is None:
            return self._finish()
        # the bag's summary is written off a composed process's control thread
        self.finisher = threading.Thread(target=self._finish, name='bag_finish')
        self.finisher.start()

    def _events(self, topic):
        """Count and log DDS's lost-message and incompatible-QoS events of ``topic``."""
        def lost(info):
            n = int(getattr(info, 'total_count_change', 1)) or 1
            self.lost += n
            self.get_logger().error('lost %d message(s) of %s (DDS message_lost)' % (n, topic))

        def incompatible(info):
            self.incompatible += 1
            self.get_logger().error('incompatible QoS on %s: policy %s'
                                    % (topic, getattr(info, 'last_policy_kind', '?')))
        return SubscriptionEventCallbacks(message_lost=lost, incompatible_qos=incompatible)

    def flush(self):
        """Write the pending mcap chunk to the file (a failure: :meth:`stopped_early`)."""
        if not self.closed and not self.sink.flush():
            self.stopped_early()

    def _diag_values(self):
        """Report counts, lost and incompatible-QoS events on ``/diagnostics``."""
        bad, stopped = self.lost or self.incompatible, self.bag.stopped
        slow = ['%s (%s)' % (r.topic, r.encode.fallback) for r in self.local.values()
                if r.encode is not None and r.encode.fallback]
        self.health.summary(ERROR if stopped else WARN if bad else OK, stopped or (
            'lost %d message(s), %d incompatible QoS' % (self.lost, self.incompatible)
            if bad else 'recording %s' % (self.output or 'snapshots only')))
        if stopped:                     # a full disk: the graph runs on, its bag ends here
            self.health.set_values(**{STOPPED_EARLY: stopped})
        if slow:
            # still every message, at rclpy's cost: worth knowing, not an error
            self.health.set_values(cdr_fallback='; '.join(slow))
        # every wanted topic, 0 until subscribed: a reader of these counts sees a
        # topic the recorder has not picked up yet as behind, not as absent
        self.health.set_values(lost=self.lost, incompatible_qos=self.incompatible,
                               closed=self.closed, **self.flight.values(),
                               **{'recorded.' + t: self.counts.get(t, 0) for t in self.wanted})

    def destroy_node(self):
        """Finalise the bag (:meth:`close`), then destroy the node."""
        self.close()
        return super().destroy_node()

    def close(self):
        """Finalise the bag (idempotent); log and return the message counts per topic."""
        if self.finisher is not None:
            self.finisher.join()
        self.flight.close()             # a pending snapshot: what the rings hold now
        if self.closed:
            return self.counts
        self.closed = True
        self._leave()
        return self._finish()

    def _leave(self):
        """Take no more messages: leave the bus, destroy the subscriptions."""
        for rec in self.local.values():
            rec.destroy()
        for sub in self.subs.values():
            if sub is not None:
                self.destroy_subscription(sub)
        self.subs = {t: None for t in self.subs}

    def _finish(self):
        """Close the bag, log the counts and write the counts files; return the counts."""
        info, warning = self.sink.finish(self.output, self.counts_file, {
            'lost': self.lost, 'incompatible_qos': self.incompatible})
        self.get_logger().info(info)
        if warning:                     # the disk that stopped the recording
            self.get_logger().warning(warning)
        return self.counts


def main(args=None):
    """
    Run the recorder until SIGINT, SIGTERM or shutdown; the bag is always finalised.

    A signal only ends the spin: the messages already queued are still taken and
    written before the bag is closed (until 0.2 s pass without one, 3 s at most; 0.5 s
    once the parent died: ``bringup`` or ``ros2 launch`` killed wants its graph gone
    within 2 s). The realtime (events) executor: the wait-set loop would cost a core.
    """
    return run_node(BagRecorder, SPEC.node, args, realtime=lambda node: True,
                    then=lambda ex, node: spin_until_quiet(
                        ex, lambda: sum(node.counts.values()), 0.2,
                        lambda: 0.5 if lifeline.parent_gone() else 3.0))


if __name__ == '__main__':
    sys.exit(main())
