# SPDX-License-Identifier: Apache-2.0
"""
``bag_recorder``: record the graph's topics into a rosbag2 (version 9) bag with rosbags.

Parameters (defaults in ``config/recorder.yaml``, node ``bag_recorder``):

* ``output`` (str): bag directory to create; empty = ``fiber_align_<YYYYmmdd_HHMMSS>``.
* ``storage`` (str): ``mcap`` or ``sqlite3``.
* ``topics`` (str[]): names to record; relative names resolve in the node's namespace.
* ``discovery_period_s`` (s): how often to look for publishers of not-yet-subscribed topics.
* ``queue_depth`` (messages): history depth of every subscription.
* ``counts_file`` (bool): write ``recorder_counts.json`` (messages per topic) in the bag.

A topic is subscribed (``raw=True``: the CDR bytes are written as received, stamped with
the wall-clock receive time in ns) once a publisher shows its type. The QoS follows the
publishers: reliable if all are reliable, transient-local if all are (the graph's
per-sample topics: a late subscription still gets the writer's seconds of history), and
``queue_depth`` deep. Every message is written in its callback, so whatever reached the
node is in the bag; on SIGINT, SIGTERM or rclpy shutdown the spin ends and the bag is
closed (finalised). A second signal during the close changes nothing.

Nothing is lost silently: the DDS ``message_lost`` and ``incompatible_qos`` events of
every subscription are counted, logged and reported on ``/diagnostics`` (``lost``,
``incompatible_qos``, and ``recorded.<topic>`` per wanted topic, every
``diagnostics_period_s``) and in ``recorder_counts.json``.

Crash safety (mcap): every ``flush_period_s`` the pending chunk is closed and written
to the file, so a recorder killed with SIGKILL (or a power cut) leaves a file whose
complete chunks ``fiber-align bag-repair DIR`` turns into a readable bag: at worst the
last ``flush_period_s`` is lost.
"""

from datetime import datetime
import json
import os
import signal
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from fiber_align.analysis import bag as bagio
from fiber_align.config import ConfigError
from fiber_align.nodes import _common as c
from fiber_align.nodes._common import DIAG_QOS, make_executor, set_realtime_priority
from fiber_align.nodes._msgtypes import message_class
from fiber_align.nodes._runtime import StopFlag

NODE_NAME = 'bag_recorder'
AREA_FILES = ('recorder.yaml',)


def _default_output():
    return 'fiber_align_' + datetime.now().strftime('%Y%m%d_%H%M%S')


class BagRecorder(Node):
    """Subscribe raw to the requested topics as they appear and write them to a bag."""

    def __init__(self, **kwargs):
        """Declare the parameters, open the bag and start discovery."""
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        ro = True
        self.output = c.declare(self, d, 'output', 'bag directory to create (must not '
                                'exist); empty: fiber_align_<date_time>', read_only=ro) \
            or _default_output()
        storage = c.declare(self, d, 'storage', 'bag storage', read_only=ro,
                            choices=('mcap', 'sqlite3'))
        c.declare(self, d, 'topics', 'topics to record (relative names resolve in the '
                  'namespace)', read_only=ro)
        period = c.declare(self, d, 'discovery_period_s', 'topic discovery period (s)',
                           0.01, 60.0, ro)
        self.depth = c.declare(self, d, 'queue_depth', 'reader history per topic '
                               '(messages)', 1, 10_000_000, ro)
        self.counts_file = c.declare(self, d, 'counts_file', 'write recorder_events.json '
                                     'next to the bag (bool)', read_only=ro)
        c.declare(self, d, 'flush_period_s', 'period of mcap chunk flushes (s)', 0.01,
                  60.0, ro)
        c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)', 0.01, 60.0, ro)
        c.declare_priority(self, d)
        gp = self.get_parameter
        self.wanted = [self.resolve_topic_name(t) for t in gp('topics').value]
        from rosbags.rosbag2 import Writer
        self.typestore = bagio.typestore()
        if os.path.exists(self.output):
            raise ConfigError('output %s exists already; choose a new bag directory'
                              % self.output)
        self.writer = Writer(self.output, version=9,
                             storage_plugin=bagio.storage_plugin(storage))
        self.writer.open()
        self.closed = False
        self.subs = {}
        self.conns = {}
        self.counts = {}
        self.lost = 0
        self.incompatible = 0
        self.timer = self.create_timer(period, self.discover)
        flush = float(gp('flush_period_s').value)
        if flush > 0:
            self.create_timer(flush, self.flush)
        self._diag_type = DiagnosticArray
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', DIAG_QOS)
        self.create_timer(float(gp('diagnostics_period_s').value), self.publish_diagnostics)
        self.get_logger().info('recording %s into %s (%s)'
                               % (', '.join(self.wanted), self.output, storage))
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
        """Subscribe to every wanted topic whose type is now known."""
        if self.closed:
            return
        types = dict(self.get_topic_names_and_types())
        for topic in self.wanted:
            if topic in self.subs or topic not in types:
                continue
            msgtype = types[topic][0]
            if not self.get_publishers_info_by_topic(topic):
                continue
            try:
                cls = message_class(msgtype)
                conn = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
            except Exception as exc:  # noqa: BLE001 - unknown type: skip it, say so
                self.get_logger().warning('cannot record %s (%s): %s' % (topic, msgtype, exc))
                self.subs[topic] = None
                continue
            self.conns[topic] = conn
            self.counts[topic] = 0
            from rclpy.event_handler import SubscriptionEventCallbacks
            events = SubscriptionEventCallbacks(
                message_lost=self._on_lost(topic), incompatible_qos=self._on_incompatible(topic))
            self.subs[topic] = self.create_subscription(
                cls, topic, self._callback(topic, conn), self._qos(topic), raw=True,
                event_callbacks=events)
            self.get_logger().info('subscribed to %s (%s)' % (topic, msgtype))

    def _callback(self, topic, conn):
        write = self.writer.write

        def cb(data):
            if self.closed:
                return
            write(conn, time.time_ns(), data)
            self.counts[topic] += 1
        return cb

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

    def flush(self):
        """Close the pending mcap chunk and hand the file's buffer to the OS."""
        if self.closed:
            return
        storage = getattr(self.writer, 'storage', None)
        chunk = getattr(storage, 'chunk', None)
        if chunk is not None and chunk.bio.tell() and hasattr(storage, 'close_chunk'):
            storage.close_chunk()
        bio = getattr(storage, 'bio', None)
        if bio is not None:
            bio.flush()

    def publish_diagnostics(self):
        """Report counts, lost and incompatible-QoS events on ``/diagnostics``."""
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
        level = 0 if not (self.lost or self.incompatible) else 1
        msg = ('recording %s' % self.output) if not level else (
            'lost %d message(s), %d incompatible QoS' % (self.lost, self.incompatible))
        st = DiagnosticStatus(level=bytes([level]), name=self.get_fully_qualified_name(),
                              message=msg, hardware_id='fiber_align')
        vals = {'lost': self.lost, 'incompatible_qos': self.incompatible,
                'closed': self.closed}
        # every wanted topic, 0 until subscribed: a reader of these counts sees a
        # topic the recorder has not picked up yet as behind, not as absent
        vals.update({'recorded.' + t: self.counts.get(t, 0) for t in self.wanted})
        st.values = [KeyValue(key=k, value=str(v)) for k, v in vals.items()]
        arr = self._diag_type(status=[st])
        arr.header.stamp = self.get_clock().now().to_msg()
        try:
            self.pub_diag.publish(arr)
        except Exception:  # noqa: BLE001 - context already shut down at exit
            pass

    def close(self):
        """Finalise the bag (idempotent); log and return the message counts per topic."""
        if self.closed:
            return self.counts
        self.closed = True
        self.writer.close()
        msg = ', '.join('%s: %d' % kv for kv in sorted(self.counts.items())) or 'no topics'
        self.get_logger().info('bag %s closed; messages per topic: %s' % (self.output, msg))
        if self.counts_file:
            with open(os.path.join(self.output, 'recorder_counts.json'), 'w',
                      encoding='utf-8') as f:
                json.dump(self.counts, f, indent=1, sort_keys=True)
            with open(os.path.join(self.output, 'recorder_events.json'), 'w',
                      encoding='utf-8') as f:
                json.dump({'lost': self.lost, 'incompatible_qos': self.incompatible}, f)
        return self.counts


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

    The node installs its own SIGINT/SIGTERM handlers: they only stop the spin loop, so
    the messages already queued for the node are still taken and written before the
    bag is closed.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopFlag()               # no lock in a handler: a nested signal would deadlock
    parent = os.getppid()

    def on_signal(signum, frame):
        stop.set()
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    code = 0
    try:
        node = BagRecorder()
        prio = int(node.get_parameter('realtime_priority').value)
        if prio:
            node.get_logger().info('scheduling: %s' % set_realtime_priority(
                prio, node.get_parameter('lock_memory').value))
        # the C++ events executor: about 9,000 messages a second at 1 kHz, where the
        # Python wait-set loop of the SingleThreadedExecutor costs most of a core
        executor = make_executor(True)
        executor.add_node(node)
        while rclpy.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
        # a parent that died (bringup killed: PR_SET_PDEATHSIG) wants every process of
        # its graph gone within 2 s, while the graph may publish until its own exit:
        # take what is queued for a moment, then close the bag. Asked on every turn: the
        # signal comes when the parent's forking thread exits, and while its other
        # threads still exit getppid() is unchanged (seen: a 1.1 s drain, then a second
        # SIGTERM 37 ms later)
        _drain(executor, node, lambda: os.getppid() != parent)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        print('bag_recorder: error: %s' % exc, file=sys.stderr, flush=True)
        code = 2
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
