# SPDX-License-Identifier: Apache-2.0
"""
``bag_recorder``: record the graph's topics into a rosbag2 (version 9) bag with rosbags.

Stands in for rosbag2's recorder (``ros2 bag record``), which a pip install of ROS 2 lacks.
Parameters: ``config/recorder.yaml``. A topic is subscribed raw (the CDR bytes written as
received, stamped with the wall-clock receive time in ns) once a publisher shows its type,
with the publishers' QoS. In-process (hosted in ``control_graph`` on its
:class:`~fiber_align.nodes.ros.bus.LocalBus`) a topic a node of the process publishes is
taken from the bus as the message object and its CDR made here
(:mod:`fiber_align.nodes.ros.cdr`); nothing of it goes through DDS. Lost messages,
incompatible QoS, the finalised bag after any stop or a full disk (``analysis.bag.guard``)
and the crash safety of the mcap chunks (``fiber-align bag-repair``): docs/ros_interface.md.
``record`` false: no bag; the flight recorder (``snapshots``,
:mod:`fiber_align.nodes.ros.flight`) keeps the last seconds of every topic and writes a
snapshot bag on a trigger, with the full recording on or off (docs/records.md).
"""

from datetime import datetime
import os
import sys
import threading
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fiber_align import lifeline
from fiber_align.analysis import bag as bagio
from fiber_align.analysis.bag.flight import NoBag
from fiber_align.analysis.bag.guard import GuardedBag, write_json
from fiber_align.analysis.recording import STOPPED_EARLY
from fiber_align.config import ConfigError
from fiber_align.graph.ranges import RECORDER_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes._msgtypes import message_class
from fiber_align.graph.endpoints import type_name
from fiber_align.nodes.ros.bus import LocalSub, sender_of, slack_of
from fiber_align.nodes.ros.cdr import encoder
from fiber_align.nodes.ros.diagnostics import ERROR, Health, OK, WARN
from fiber_align.nodes.ros.flight import FlightROS
from fiber_align.nodes.ros.params import declare, declare_graph_values, declare_row
from fiber_align.nodes.ros.params import node_defaults, PRIORITY
from fiber_align.nodes.ros.runtime import run_node

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
        from rosbags.rosbag2 import Writer
        self.typestore = bagio.typestore()
        self.flight = FlightROS(self, d, len(self.wanted), storage)
        if not self.record:
            self.output, self.bag = '', NoBag()
        elif os.path.exists(self.output):
            raise ConfigError('output %s exists already; choose a new bag directory'
                              % self.output)
        else:
            self.writer = Writer(self.output, version=9,
                                 storage_plugin=bagio.storage_plugin(storage))
            self.writer.open()
            self.bag = GuardedBag(self.writer)     # a full disk: the bag closed readable
        self.closed, self.finisher = False, None
        self.subs = {}
        self.keep = {}          # topic -> the flight recorder's append, or None
        self.conns = {}
        self.counts = {}
        self.lost = 0
        self.incompatible = 0
        self.flush_s = float(gp('flush_period_s').value)
        self.bus = bus
        self.local = {}         # topic -> _Local: recorded in-process
        self.t_flush = time.monotonic()     # the last chunk close (monotonic s)
        if bus is not None:
            for topic in self.wanted:
                if topic in bus.topics:
                    self.counts[topic] = 0      # a latched message arrives at once
                    self.local[topic] = _Local(self, topic)
            # the control thread's slack runs the discovery and the writes
            self.timer = self.create_timer(period, lambda: bus.slack.submit(self.discover))
        else:
            self.timer = self.create_timer(period, self.discover)
            if self.flush_s > 0:
                self.create_timer(self.flush_s, self.flush)
        self.health = Health(self, float(gp('diagnostics_period_s').value),
                             update=self._diag_values,
                             slack=slack_of(bus), sender=sender_of(bus))
        self.get_logger().info('recording %s into %s (%s)' % (
            ', '.join(self.wanted), self.output or 'no bag', storage))
        self.discover()

    def _qos(self, topic):
        infos = self.get_publishers_info_by_topic(topic)
        rel = ReliabilityPolicy.RELIABLE
        dur = DurabilityPolicy.VOLATILE
        if infos:
            if any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos):
                rel = ReliabilityPolicy.BEST_EFFORT
            if all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos):
                dur = DurabilityPolicy.TRANSIENT_LOCAL
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self.depth,
                          reliability=rel, durability=dur)

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
                conn = self.bag.add_connection(topic, msgtype, typestore=self.typestore)
            except Exception as exc:  # noqa: BLE001 - unknown type: skip it, say so
                self.get_logger().warning('cannot record %s (%s): %s' % (topic, msgtype, exc))
                self.subs[topic] = None
                continue
            self.conns[topic] = conn
            self.counts[topic] = 0
            self.keep[topic] = self.flight.keeper(topic, msgtype)
            from rclpy.event_handler import SubscriptionEventCallbacks
            events = SubscriptionEventCallbacks(
                message_lost=self._on_lost(topic), incompatible_qos=self._on_incompatible(topic))
            self.subs[topic] = self.create_subscription(
                cls, topic, self._callback(topic, conn), self._qos(topic), raw=True,
                event_callbacks=events)
            self.get_logger().info('subscribed to %s (%s)' % (topic, msgtype))

    def _callback(self, topic, conn):
        write, keep = self.bag.write, self.keep[topic]

        def cb(data):
            if self.closed:
                return
            t_ns = time.time_ns()
            if keep is not None:
                keep(t_ns, data)
            if not write(conn, t_ns, data):
                return self.stopped_early()
            self.counts[topic] += 1
        return cb

    def stopped_early(self):
        """Stop recording after a failed write (a full disk): one line; the graph runs on."""
        if self.closed:
            return
        self.closed = True              # no more writes; _finish closes the bag
        self.get_logger().error(self.bag.stopped)
        for sub in self.subs.values():
            if sub is not None:
                self.destroy_subscription(sub)
        self.subs = {t: None for t in self.subs}
        for rec in self.local.values():
            rec.destroy()
        if self.bus is None:
            return self._finish()
        # the bag's summary is written off a composed process's control thread
        self.finisher = threading.Thread(target=self._finish, name='bag_finish')
        self.finisher.start()

    def _on_lost(self, topic):
        def cb(info):
            n = int(getattr(info, 'total_count_change', 1)) or 1
            self.lost += n
            self.get_logger().error('lost %d message(s) of %s (DDS message_lost)'
                                    % (n, topic))
        return cb

    def _on_incompatible(self, topic):
        def cb(info):
            self.incompatible += 1
            self.get_logger().error('incompatible QoS on %s: policy %s'
                                    % (topic, getattr(info, 'last_policy_kind', '?')))
        return cb

    def flush_due(self):
        """Close the chunk (:meth:`flush`) when ``flush_period_s`` has passed (in-process)."""
        now = time.monotonic()
        if self.flush_s > 0 and now - self.t_flush >= self.flush_s and not self.closed:
            self.t_flush = now
            self.flush()

    def flush(self):
        """Write the pending mcap chunk to the file (a failure: :meth:`stopped_early`)."""
        if not self.closed and not self.bag.flush():
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
        for rec in self.local.values():
            rec.destroy()
        return self._finish()

    def _finish(self):
        """Close the bag, log the counts and write the counts files; return the counts."""
        why = self.bag.close()
        if self.bag.stopped:
            self.counts.update(self.bag.counts())   # the bag's: a cut chunk is not in it
        msg = ', '.join('%s: %d' % kv for kv in sorted(self.counts.items())) or 'no topics'
        self.get_logger().info('bag %s closed%s; messages per topic: %s' % (
            self.output or '(none: snapshots only)', (' (%s)' % why) if why else '', msg))
        why = self.counts_file and self.record and write_json(self.output, {
            'recorder_counts.json': self.counts,
            'recorder_events.json': {'lost': self.lost, 'incompatible_qos': self.incompatible}})
        if why:                         # the disk that stopped the recording
            self.get_logger().warning('no recorder_counts.json: %s' % why)
        return self.counts


class _Local:
    """One topic recorded in-process: its bus subscription, CDR encoder and connection."""

    def __init__(self, rec, topic):
        """Subscribe on ``rec``'s bus; the type is the first message's."""
        self.rec, self.topic = rec, topic
        self.encode = None
        self.conn = None
        self.connected = False          # a snapshots-only bag gives no connection (None)
        self.msgtype = ''
        self.keep = None
        self.sub = LocalSub(rec.bus, topic, self._on_message)

    def _on_message(self, msg):
        rec = self.rec
        if rec.closed:
            return
        if self.encode is None:
            self.msgtype = type_name(type(msg))
            self.encode = encoder(rec.typestore, self.msgtype, type(msg))
        if not self.connected:
            self.connect()
        # written at once, a few microseconds; so is the chunk close when due: its cost
        # grows with the chunk, so it is kept small and regular (deferred to a later
        # slack it only grew)
        t_ns, data = time.time_ns(), self.encode(msg)
        if self.keep is not None:
            self.keep(t_ns, data)
        if not rec.bag.write(self.conn, t_ns, data):
            return rec.stopped_early()
        rec.counts[self.topic] += 1
        rec.flush_due()

    def connect(self):
        """Add the bag connection (once, on the first write)."""
        self.conn = self.rec.bag.add_connection(self.topic, self.msgtype,
                                                typestore=self.rec.typestore)
        self.connected = True
        self.keep = self.rec.flight.keeper(self.topic, self.msgtype)
        self.rec.get_logger().info('recording %s (%s) in-process'
                                   % (self.topic, self.msgtype))

    def destroy(self):
        """Leave the bus."""
        self.sub.destroy()


def _drain(executor, node, orphaned, quiet_s=0.2, limit_s=3.0, orphan_limit_s=0.5):
    """
    Run callbacks until none has run for ``quiet_s`` s (at most ``limit_s`` s).

    :param orphaned: callable, True once the parent died; from then on the drain ends
        ``orphan_limit_s`` s after it began.
    """
    t0 = time.monotonic()
    last, quiet_since = sum(node.counts.values()), t0
    while rclpy.ok() and time.monotonic() - t0 < (orphan_limit_s if orphaned() else limit_s):
        executor.spin_once(timeout_sec=0.02)
        now_count = sum(node.counts.values())
        if now_count != last:
            last, quiet_since = now_count, time.monotonic()
        elif time.monotonic() - quiet_since >= quiet_s:
            break


def main(args=None):
    """
    Run the recorder until SIGINT, SIGTERM or shutdown; the bag is always finalised.

    A signal only ends the spin: the messages already queued are still taken and
    written (:func:`_drain`) before the bag is closed (:meth:`BagRecorder.destroy_node`).
    The realtime (events) executor: the Python wait-set loop would cost most of a core.
    A parent that died (``bringup`` or ``ros2 launch`` killed) wants its graph gone
    within 2 s, while the graph may publish until its own exit: the drain then ends
    sooner (asked on every turn).
    """
    return run_node(BagRecorder, SPEC.node, args, realtime=lambda node: True,
                    then=lambda ex, node: _drain(ex, node, lifeline.parent_gone))


if __name__ == '__main__':
    sys.exit(main())
