# SPDX-License-Identifier: Apache-2.0
"""
One graph per set of names (docs/ros_interface.md): the start-up probe, the driver's watch.

:func:`refuse_taken`: before any node starts (launch file, ``bringup``), refuse in one line
when the graph's node names are on the graph. :class:`PublisherWatch`: one publisher per
command and drive topic (:data:`fiber_align.graph.registry.DRIVES`), counted by a thread
(``rcl_count_publishers`` by ``ctypes``, the GIL released: never on the control thread).
"""

import atexit
import ctypes
import os
import threading
import time

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from fiber_align.graph.endpoints import (drive_owners, extra_publishers, graph_names,
                                         names_taken, NamesTaken, node_fqn, started_first,
                                         starting_marker, UNKNOWN)
from fiber_align.graph.params import effective, merge_params
from fiber_align.nodes.ros.rcl_ctypes import Rcl

#: s between two counts of the watched topics' publishers (and the finding's delivery)
PERIOD_S = 0.25


def refuse_taken(graph, wait_s=None):
    """
    Raise :class:`NamesTaken` (one line) when another graph owns ``graph``'s node names.

    The probe's node is named after the start (:func:`~fiber_align.graph.endpoints.
    starting_marker`) and stays on the graph while this process runs (the launch process,
    ``bringup``): a graph of the same names started at the same moment, whose nodes are
    not up yet, is seen by its marker, and the later start is refused.

    :param wait_s: how long discovery may take (s; ``None``: ``discovery_wait_s`` of the
        ``bringup`` section of the graph's files): the listing is looked at every 50 ms.
    """
    if wait_s is None:
        wait_s = effective(merge_params(graph.params_files), 'bringup')['discovery_wait_s']
    want, domain = graph_names(graph), os.environ.get('ROS_DOMAIN_ID') or '0'
    mine = starting_marker(want, time.time_ns(), os.getpid())
    ctx = Context()
    rclpy.init(args=[], context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = Node(mine, context=ctx, enable_rosout=False, start_parameter_services=False)
        t_end, seen = time.monotonic() + float(wait_s), set()
        while time.monotonic() < t_end:
            time.sleep(0.05)
            seen.update(node.get_node_names_and_namespaces())
            if seen & want:             # found: 0.3 s more for the rest of its names
                t_end = min(t_end, time.monotonic() + 0.3)
        why = names_taken(want, seen, domain) or started_first(mine, seen, domain)
    except BaseException:
        ctx.try_shutdown()
        raise
    if why:
        ctx.try_shutdown()
        raise NamesTaken(why)
    _MARKERS.append((ctx, node))        # the marker stays until this process ends
    atexit.register(ctx.try_shutdown)


#: this process's start markers (:func:`refuse_taken`): ``(context, node)``, referenced so
#: that neither is collected (a collected node leaves the graph)
_MARKERS = []


def watch_drives(node, axes, on_change):
    """Return the :class:`PublisherWatch` of a driver's command and drive topics."""
    return PublisherWatch(node, drive_owners(node.get_fully_qualified_name(), axes), on_change)


class PublisherWatch:
    """
    The publishers of a node's command and drive topics, counted off the control thread.

    A DDS input's second matched publisher is a finding at once, before its first message
    is served (:meth:`events`, :meth:`guard`), :attr:`pending` until named.

    :param owners: ``{topic (relative): owner (fully qualified)}`` (``drive_owners``).
    :param on_change: called on the executor with the lines found when they change.
    """

    def __init__(self, node, owners, on_change, period_s=PERIOD_S):
        """Start the thread and the delivery timer."""
        self._node, self._on_change, self.period_s = node, on_change, float(period_s)
        self.owners, self._rcl = {node.resolve_topic_name(t): o for t, o in owners.items()}, Rcl()
        self._state, self._told, self._matched, self.pending = ((), False), (), {}, False
        self._stop, self._wake = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._run, name='fiber_align.owners',
                                        daemon=True)
        self._thread.start()
        self._timer = node.create_timer(self.period_s, self._deliver,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def events(self, topic):
        """Return the ``event_callbacks`` of the node's subscription to ``topic``."""
        name = self._node.resolve_topic_name(topic)
        return SubscriptionEventCallbacks(matched=lambda info: self._on_matched(
            name, info.current_count))

    def guard(self, sub):
        """
        Return ``sub`` (an rclpy Subscription) with its callback behind the match count.

        Each message first reads the subscription's matched publishers: a second one
        holds before this message is served (the matched event alone can come after the
        first foreign messages on a loaded machine; docs/ros_interface.md).
        """
        name, take = sub.topic_name, sub.callback

        def guarded(msg):
            try:
                n = sub.get_publisher_count()
            except Exception:  # noqa: BLE001 - destroyed (a cleanup) after the take
                n = 0
            if n > self._matched.get(name, 1):
                self._on_matched(name, n)
            take(msg)
        sub.callback = guarded
        return sub

    def _on_matched(self, topic, n):
        self._matched[topic] = n
        if n > 1 and not self._state[0]:    # held at once, until the thread names them
            self._state = (self._unnamed(), True)
            self._deliver()
        self._wake.set()

    def _unnamed(self, counts=None):
        return tuple('%s: %d publishers matched, 1 expected' % (t, n)
                     for t, n in sorted(self._matched.items())
                     if n > 1 and (counts is None or counts.get(t, 0) < n))

    def _count(self, topic):
        n, h = ctypes.c_size_t(), self._node.handle
        with h:     # in use: a destroy waits; after one, InvalidHandle ends the thread
            failed = self._rcl.count_publishers(h.pointer, topic.encode(), ctypes.byref(n))
        return 0 if failed and self._rcl.reset_error() is None else n.value

    def _run(self):
        while not self._stop.is_set():
            self._wake.wait(self.period_s)
            self._wake.clear()
            try:
                counts = {t: self._count(t) for t in self.owners}
                # the names (rclpy's query, the GIL held for it): only for such a topic
                pubs = {t: [node_fqn(i.node_name, i.node_namespace) for i in
                            self._node.get_publishers_info_by_topic(t)]
                        for t, n in counts.items() if n > 1}
            except Exception:  # noqa: BLE001 - the node is being destroyed
                return
            # a match the graph's listing does not show, or not by name yet, stands
            known = {t: v for t, v in pubs.items() if not any(UNKNOWN in n for n in v)}
            named = tuple(extra_publishers(self.owners, known))
            lag = () if named else self._unnamed({t: counts[t] for t in known})
            self._state = (named or lag, bool(lag))

    def _deliver(self):
        found, pending = self._state
        if found != self._told:
            self._told, self.pending = found, pending
            self._on_change(list(found))

    def close(self):
        """Stop the thread (before the node is destroyed) and the timer; return None."""
        self._stop.set()
        self._thread.join(2.0)          # within a period
        self._node.destroy_timer(self._timer)
