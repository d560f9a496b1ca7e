# SPDX-License-Identifier: Apache-2.0
"""
In-process delivery between the nodes of one process.

:class:`LocalBus` stands in for rclcpp's intra-process communication, which rclpy (a pip
install of ROS 2) lacks: messages between the nodes of ``control_graph`` go by a direct
call, while every message is still published to DDS for the readers outside.
"""

from fiber_align.control.cycle import Slack
from fiber_align.nodes.ros.sender import Writer


class LocalBus:
    """
    In-process delivery between the nodes of one process (the composed graph).

    A node built with a bus publishes through :class:`Pub`: the in-process subscribers'
    callbacks first, in the order they subscribed, then DDS (outside subscribers, the
    recorder first, still receive every message). A topic is delivered locally when a node
    of the process publishes it (:meth:`provide`, before the nodes are built); its
    in-process readers then create no DDS subscription (one writer per control topic).
    Topics are keyed by their fully qualified names (:meth:`key`), so the nodes of one
    process may live in several namespaces; remapping is not supported in a composed
    process.
    """

    def __init__(self, topics=()):
        """Start with the relative names in ``topics`` delivered locally."""
        self.topics = set(topics)
        self._subs = {}
        self._last = {}
        self.depth = 0          # in-process deliveries on the stack
        self.deferred = []      # (Pub, message) DDS publishes made inside them
        self.slack = Slack()    # the process's housekeeping, after each answered sample
        #: the process's :class:`~fiber_align.nodes.ros.sender.Sender` (DDS publishes off
        #: the control thread once started), or ``None``: publishes made at once
        self.sender = None
        #: period (s) -> the :class:`SampleTimer` the sample clocks of that period share
        self.timers = {}
        #: fully qualified topic -> the message class its :class:`Pub` publishes (a
        #: recorder built later prepares its encoders before the spin)
        self.types = {}

    def flush(self):
        """Hand the DDS publishes deferred by nested deliveries to DDS, in order."""
        while self.deferred:
            pub, msg = self.deferred.pop(0)
            pub.send(msg)

    def provide(self, *topics):
        """Mark ``topics`` (fully qualified names) as published inside this process."""
        self.topics.update(topics)

    @staticmethod
    def key(node, topic):
        """Return the fully qualified name of ``topic`` as ``node`` resolves it."""
        return node.resolve_topic_name(topic)

    def local(self, node, topic):
        """Return True when ``topic`` of ``node`` is delivered inside this process."""
        return self.key(node, topic) in self.topics

    def callbacks(self, topic):
        """Return the (live) list of in-process callbacks of ``topic``."""
        return self._subs.setdefault(topic, [])

    def deliver(self, node, topic, msg):
        """
        Hand ``msg`` of a plain rclpy publisher of ``node`` to the in-process readers.

        Latched: a reader built later (the recorder, built last) gets the newest at once.
        """
        key = self.key(node, topic)
        self.latch(key, msg)
        for cb in tuple(self._subs.get(key, ())):
            cb(msg)

    def latch(self, topic, msg):
        """Keep ``msg`` as the latched message of ``topic`` (given to late subscribers)."""
        self._last[topic] = msg

    def last(self, topic):
        """Return the latched message of ``topic`` or ``None``."""
        return self._last.get(topic)


def local_too(pub, bus, node, topic):
    """
    Return ``msg -> None``: ``pub.publish(msg)``, then the in-process readers of ``topic``.

    For a low-rate topic on its own rclpy publisher that the composed recorder reads.
    """
    if bus is None:
        return pub.publish

    def publish(msg):
        pub.publish(msg)
        bus.deliver(node, topic, msg)
    return publish


class Pub:
    """A publisher that also delivers to the in-process subscribers of a :class:`LocalBus`."""

    __slots__ = ('pub', 'topic', 'topic_name', '_local', '_bus', '_latched', '_slack',
                 '_writer')

    def __init__(self, node, msg_type, topic, qos, bus=None, latched=False, slack=None):
        """
        Create the DDS publisher of ``topic`` (relative name) with ``qos``.

        :param slack: the :class:`~fiber_align.control.cycle.Slack` of a node's per-sample
            output: told after each outermost publish that a cycle's work is done.
        """
        from rclpy.qos import DurabilityPolicy
        self.pub = node.create_publisher(msg_type, topic, qos)
        self._writer = writer_of(self.pub, qos.durability == DurabilityPolicy.VOLATILE,
                                 bus)
        self.topic_name = self.pub.topic_name
        self.topic = self.topic_name    # the bus's key: the fully qualified name
        self._bus = bus if bus is not None and bus.local(node, topic) else None
        self._local = self._bus.callbacks(self.topic) if self._bus is not None else ()
        if self._bus is not None:
            self._bus.types[self.topic] = msg_type
        self._latched = latched
        self._slack = slack

    def publish(self, msg):
        """
        Deliver ``msg`` to every in-process subscriber, then publish it to DDS.

        DDS after the outermost delivery: the loop's chain (sample, feedforward, feedback,
        drive) runs inside the plant's publish, so the drive reaches the plant before any
        DDS publish is paid; outside readers get every message, in order, just later.
        """
        bus = self._bus
        if bus is None:
            self.send(msg)
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
            bus.deferred.append((self, msg))
        else:
            self.send(msg)
            bus.flush()
            if self._slack is not None:
                self._slack.after_cycle()

    def send(self, msg):
        """Publish ``msg`` to DDS (:class:`~fiber_align.nodes.ros.sender.Writer`)."""
        self._writer.publish(msg)

    def get_subscription_count(self):
        """Return the DDS subscription count (in-process readers not included)."""
        return self.pub.get_subscription_count()

    def destroy(self, node):
        """Destroy the DDS publisher (detached from the sender first)."""
        if self._writer.sender is not None:
            self._writer.sender.forget(self._writer)
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


class SampleTimer:
    """
    One wall-clock timer that ticks every realtime sample clock of a process in turn.

    The plants of one process tick from one callback in the order built, each at the
    timer's scheduled time (a second plant is not late for the first one's loop), then the
    drivers' watchdogs: one executor wake a period, not one per clock. A watchdog pauses
    while every plant is held (``~/run`` false); a plant's callback returns True while
    its clock runs.
    """

    def __init__(self, node, period_s, clock, slack=None):
        """
        Create the timer on ``node`` (period in s, ``clock`` rclpy steady clock).

        :param slack: the process's :class:`~fiber_align.control.cycle.Slack`: its
            housekeeping runs after the whole tick, every sample clock answered.
        """
        self.callbacks = []
        self.watchdogs = set()      # callbacks that pause while every plant is held
        self.slack = slack
        self.timer = node.create_timer(period_s, self._tick, clock=clock)

    def _tick(self):
        slack = self.slack
        if slack is not None and len(self.callbacks) > 1:
            slack.in_tick = True
            try:
                self._run()
            finally:
                slack.end_tick()
            return
        self._run()

    def _run(self):
        ran = None                  # a plant's clock ran this tick (None: no plant)
        watchdogs = self.watchdogs
        for cb in self.callbacks:
            if cb not in watchdogs:
                ran = bool(cb()) or bool(ran)
            elif ran is not False:
                cb()

    def time_until_next_call(self):
        """Return the time (ns) until the next tick, as rclpy's ``Timer``."""
        return self.timer.time_until_next_call()

    def remove(self, callback):
        """Tick ``callback`` no more (a driver cleaned up)."""
        if callback in self.callbacks:
            self.callbacks.remove(callback)
        self.watchdogs.discard(callback)


def sample_timer(node, bus, period_s, callback, clock, watchdog=False):
    """
    Return the timer of a realtime sample clock calling ``callback`` every ``period_s``.

    Composed (``bus`` given): the process's :class:`SampleTimer` of that period, shared
    with the other sample clocks of the process; else a timer of ``node`` of its own.

    :param watchdog: ``callback`` is a driver's watchdog: composed, it pauses while every
        plant of the process is held.
    """
    if bus is None:
        return node.create_timer(period_s, callback, clock=clock)
    shared = bus.timers.get(period_s)
    if shared is None:
        shared = bus.timers[period_s] = SampleTimer(node, period_s, clock, bus.slack)
    shared.callbacks.append(callback)
    if watchdog:
        shared.watchdogs.add(callback)
    return shared


def release_timer(node, timer, callback):
    """Stop a timer made by :func:`sample_timer` for ``callback`` (shared or ``node``'s own)."""
    if isinstance(timer, SampleTimer):
        timer.remove(callback)
    else:
        node.destroy_timer(timer)


def writer_of(pub, volatile, bus=None):
    """Return the ``sender.Writer`` of rclpy publisher ``pub`` (on ``bus``'s sender if any)."""
    sender = sender_of(bus)
    return sender.writer(pub, volatile) if sender is not None else Writer(pub, volatile)


def sender_of(bus):
    """Return the ``sender.Sender`` of a node's process, or None."""
    return bus.sender if bus is not None else None


def slack_of(bus):
    """Return the housekeeping of a node's process: its bus's (composed), else a new one."""
    return bus.slack if bus is not None else Slack()


def subscription(node, msg_type, topic, callback, qos, bus=None, watch=None):
    """
    Subscribe ``callback`` to ``topic`` (relative name) locally or through DDS.

    :param watch: a :class:`~fiber_align.nodes.ros.owners.PublisherWatch` of the topic's
        publishers (a DDS subscription only: nothing else reaches one in-process).

    :returns: a :class:`LocalSub` when a node of this process publishes ``topic`` on
        ``bus``, else the rclpy Subscription.
    """
    if bus is not None and bus.local(node, topic):
        return LocalSub(bus, bus.key(node, topic), callback)
    sub = node.create_subscription(msg_type, topic, callback, qos,
                                   event_callbacks=watch and watch.events(topic))
    return watch.guard(sub) if watch is not None else sub


def unsubscribe(node, sub):
    """Destroy a subscription made by :func:`subscription`."""
    if isinstance(sub, LocalSub):
        sub.destroy()
    elif sub is not None:
        node.destroy_subscription(sub)
