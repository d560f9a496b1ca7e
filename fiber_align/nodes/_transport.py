# SPDX-License-Identifier: Apache-2.0
"""
Transport of the fiber_align nodes: the QoS profiles and in-process delivery.

The QoS is chosen so that nothing a publisher sent is lost silently and no control reader
works through a backlog (docs/ros_interface.md, "Topics"). :class:`LocalBus` delivers
messages between the nodes of one process (``control_graph``) by a direct call, while
every message is still published to DDS.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fiber_align.nodes._cycle import Slack

#: Seconds of history every per-sample publisher keeps (``displacement``,
#: ``feedforward_voltage``, ``feedback_voltage``, ``drive_voltage``, ``reference``,
#: ``optical_power``, ``controller_state``): a reader that falls behind (the recorder on a
#: loaded machine) catches up from the writer's history instead of losing samples, and
#: the writer never blocks on it (KEEP_LAST drops the oldest only after this long).
SAMPLE_HISTORY_S = 5.0
#: The same as a depth (messages) at the default 1 kHz; see :func:`sample_pub_qos`.
SAMPLE_DEPTH = 5000
#: Per-sample publishers: reliable, ``SAMPLE_HISTORY_S`` of history, transient local, so
#: a reader that matched the writer a moment after a sample was published (multi-process
#: lockstep start-up) still receives it: the first sample can no longer be lost in the
#: discovery race that used to stall one lockstep start in four.
CONTROL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Lockstep readers of the per-sample topics: reliable, deep and transient local (index
#: pairing needs every message, including one published before the match completed).
LOCKSTEP_QOS = CONTROL_QOS
#: ``/clock``: reliable publisher, matched by the best-effort subscriber of rclpy's
#: TimeSource; as deep as the control topics so a lagging recorder loses no tick, and
#: transient local like them: under ``ros2 launch`` the plant starts without waiting for
#: the recorder, which met a short lockstep run's /clock only after its last tick (seen
#: with two CPU hogs: a bag without /clock).
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
DIAG_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE)
#: Realtime control readers of the per-sample topics: only the newest message matters,
#: so a node that fell behind skips stale samples instead of working through a backlog.
#: Best effort, as ROS's sensor-data profile: a reliable reader delivers in order, so one
#: sample lost on the way would hold every newer one until its repair, and a newest-only
#: reader has no use for the lost one. Volatile (no stale history on joining). Matches
#: the reliable publishers.
REALTIME_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                          reliability=ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)
#: The realtime simulated plant's ``drive_voltage`` reader: the DAC it stands for sees
#: every value the driver wrote, so after a stall of its process it can replay the ones
#: written meanwhile (:mod:`fiber_align.plant.dac`); best effort and volatile as
#: :data:`REALTIME_QOS`, but as deep as the per-sample history.
DAC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                     reliability=ReliabilityPolicy.BEST_EFFORT,
                     durability=DurabilityPolicy.VOLATILE)
#: State topics published on change only (``drive_held``): a late joiner (e.g. a restarted
#: controller) gets the present state at once.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: The user's ``setpoint`` (one consumer: ``hysteresis_compensator``): reliable, volatile,
#: deep (every setpoint is checked, so each bad one is reported); a default rclpy or
#: ``ros2 topic pub`` publisher (reliable, volatile, depth 10) matches it.
SETPOINT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
#: ``reference`` as the realtime controller reads it: the newest accepted setpoint,
#: latched, so a restarted controller takes the present setpoint without a re-send.
REFERENCE_LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)


class LocalBus:
    """
    In-process delivery between the nodes of one process (the composed graph).

    ``rclpy`` has no intra-process transport: without this, a message between two nodes
    of one process is serialised, handed to DDS and delivered back through the executor.
    A node built with a bus publishes through :class:`Pub`, which calls the in-process
    subscribers' callbacks directly, in the order they subscribed, and then hands the
    message to DDS (so outside subscribers, the recorder first, still receive every one).
    A topic is delivered locally when a node of the process publishes it
    (:meth:`provide`, before the nodes are built); its in-process readers then create no
    DDS subscription, so an outside publisher on that topic is not heard by them (one
    writer per control topic). Names are the relative names the nodes use (one
    namespace per process; remapping is not supported in a composed process).
    """

    def __init__(self, topics=()):
        """Start with the relative names in ``topics`` delivered locally."""
        self.topics = set(topics)
        self._subs = {}
        self._last = {}
        self.depth = 0          # in-process deliveries on the stack
        self.deferred = []      # (publisher, message) DDS publishes made inside them
        self.slack = Slack()    # the process's housekeeping, after each answered sample

    def flush(self):
        """Hand the DDS publishes deferred by nested deliveries to DDS, in order."""
        while self.deferred:
            pub, msg = self.deferred.pop(0)
            pub.publish(msg)

    def provide(self, *topics):
        """Mark ``topics`` (relative names) as published inside this process."""
        self.topics.update(topics)

    def local(self, topic):
        """Return True when ``topic`` is delivered inside this process."""
        return topic in self.topics

    def callbacks(self, topic):
        """Return the (live) list of in-process callbacks of ``topic``."""
        return self._subs.setdefault(topic, [])

    def latch(self, topic, msg):
        """Keep ``msg`` as the latched message of ``topic`` (given to late subscribers)."""
        self._last[topic] = msg

    def last(self, topic):
        """Return the latched message of ``topic`` or ``None``."""
        return self._last.get(topic)


class Pub:
    """A publisher that also delivers to the in-process subscribers of a :class:`LocalBus`."""

    __slots__ = ('pub', 'topic', 'topic_name', '_local', '_bus', '_latched', '_slack')

    def __init__(self, node, msg_type, topic, qos, bus=None, latched=False, slack=None):
        """
        Create the DDS publisher of ``topic`` (relative name) with ``qos``.

        :param slack: the :class:`~fiber_align.nodes._cycle.Slack` of a node's per-sample
            output: told after each outermost publish that a cycle's work is done.
        """
        self.pub = node.create_publisher(msg_type, topic, qos)
        self.topic = topic
        self.topic_name = self.pub.topic_name
        self._bus = bus if bus is not None and bus.local(topic) else None
        self._local = self._bus.callbacks(topic) if self._bus is not None else ()
        self._latched = latched
        self._slack = slack

    def publish(self, msg):
        """
        Deliver ``msg`` to every in-process subscriber, then publish it to DDS.

        In-process first, DDS after the outermost delivery: the loop's chain (sample,
        feedforward, feedback, drive) runs inside the plant's publish, so the drive
        reaches the plant before any of the chain's DDS publishes (10-20 us each with the
        recorder matched) is paid; outside subscribers still receive every message, in
        the order published, a few tens of microseconds later. A node publishes each
        topic once per sample, so the message objects it reuses are not changed before
        the deferred publish.
        """
        bus = self._bus
        if bus is None:
            self.pub.publish(msg)
            if self._slack is not None:
                self._slack.after_cycle()
            return
        if self._latched:
            bus.latch(self.topic, msg)
        bus.depth += 1
        try:
            for cb in tuple(self._local):
                cb(msg)
        finally:
            bus.depth -= 1
        if bus.depth:
            bus.deferred.append((self.pub, msg))
        else:
            self.pub.publish(msg)
            bus.flush()
            if self._slack is not None:
                self._slack.after_cycle()

    def get_subscription_count(self):
        """Return the DDS subscription count (in-process readers not included)."""
        return self.pub.get_subscription_count()

    def destroy(self, node):
        """Destroy the DDS publisher."""
        node.destroy_publisher(self.pub)


class LocalSub:
    """An in-process subscription of a :class:`LocalBus` (see :func:`subscription`)."""

    __slots__ = ('bus', 'topic', 'callback')

    def __init__(self, bus, topic, callback):
        """Register ``callback`` for ``topic``; a latched message is delivered at once."""
        self.bus, self.topic, self.callback = bus, topic, callback
        bus.callbacks(topic).append(callback)
        last = bus.last(topic)
        if last is not None:
            callback(last)

    def destroy(self):
        """Unregister the callback."""
        cbs = self.bus.callbacks(self.topic)
        if self.callback in cbs:
            cbs.remove(self.callback)


def slack_of(bus):
    """Return the housekeeping of a node's process: its bus's (composed), else a new one."""
    return bus.slack if bus is not None else Slack()


def subscription(node, msg_type, topic, callback, qos, bus=None):
    """
    Subscribe ``callback`` to ``topic`` (relative name) locally or through DDS.

    :returns: a :class:`LocalSub` when a node of this process publishes ``topic`` on
        ``bus``, else the rclpy Subscription.
    """
    if bus is not None and bus.local(topic):
        return LocalSub(bus, topic, callback)
    return node.create_subscription(msg_type, topic, callback, qos)


def unsubscribe(node, sub):
    """Destroy a subscription made by :func:`subscription`."""
    if isinstance(sub, LocalSub):
        sub.destroy()
    elif sub is not None:
        node.destroy_subscription(sub)


def sample_qos(lockstep):
    """
    Return the subscription QoS of a per-sample topic for the sync mode.

    :param lockstep: True in lockstep (deep queue: index pairing needs every message),
        False in realtime (newest message only, see :data:`REALTIME_QOS`).
    """
    return LOCKSTEP_QOS if lockstep else REALTIME_QOS
