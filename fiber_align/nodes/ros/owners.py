# SPDX-License-Identifier: Apache-2.0
"""
One graph per set of names: the start-up probe and the running driver's publisher watch.

:func:`refuse_taken`: before any node of a graph starts (the launch file and ``bringup``),
a node of its own looks at the graph for ``discovery_wait_s`` and refuses, in one line,
when nodes of the graph's names are there already (the comparison is pure:
:func:`fiber_align.graph.endpoints.names_taken`).

:class:`PublisherWatch`: a running driver's command and drive topics
(:data:`fiber_align.graph.registry.DRIVES`) each have one publisher; a thread of its own
counts them (``rcl_count_publishers`` by ``ctypes``, the GIL released: a graph query can
wait on DDS, so never on the control thread) every :data:`PERIOD_S`, names the
publishers of a topic that has more than one (rclpy's query, only then), and a steady
timer of the node hands a changed finding to the driver on its executor.
"""

import ctypes
import os
import threading
import time

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from fiber_align.graph.endpoints import (drive_owners, extra_publishers, graph_names,
                                         names_taken, node_fqn)
from fiber_align.graph.params import effective, GraphError, merge_params
from fiber_align.nodes.ros.rcl_ctypes import Rcl

#: s between two counts of the watched topics' publishers (and the finding's delivery)
PERIOD_S = 0.25


def domain():
    """Return the ROS_DOMAIN_ID the processes use (text; unset: 0)."""
    return os.environ.get('ROS_DOMAIN_ID') or '0'


def refuse_taken(graph, wait_s=None):
    """
    Raise :class:`GraphError` (one line) when another graph owns ``graph``'s node names.

    :param wait_s: how long discovery may take (s; ``None``: ``discovery_wait_s`` of the
        ``bringup`` section of the graph's files): the listing is looked at every 50 ms
        until a name is found or this is over.
    """
    if wait_s is None:
        wait_s = effective(merge_params(graph.params_files), 'bringup')['discovery_wait_s']
    want = graph_names(graph)
    ctx = Context()
    rclpy.init(args=[], context=ctx, signal_handler_options=SignalHandlerOptions.NO)
    why = None
    try:
        node = Node('_fiber_align_probe_%d' % os.getpid(), context=ctx,
                    enable_rosout=False, start_parameter_services=False)
        t_end = time.monotonic() + float(wait_s)
        while why is None and time.monotonic() < t_end:
            time.sleep(0.05)
            why = names_taken(want, node.get_node_names_and_namespaces(), domain())
        node.destroy_node()
    finally:
        ctx.try_shutdown()
    if why:
        raise GraphError(why)


def watch_drives(node, axes, on_change):
    """Return the :class:`PublisherWatch` of a driver's command and drive topics."""
    return PublisherWatch(node, drive_owners(node.get_fully_qualified_name(), axes),
                          on_change)


class PublisherWatch:
    """
    The publishers of a node's command and drive topics, counted off the control thread.

    :param node: the rclpy node (its graph; its executor runs the delivery timer).
    :param owners: ``{topic (relative): owner (fully qualified)}``
        (:func:`~fiber_align.graph.endpoints.drive_owners`).
    :param on_change: called on the node's executor with the lines of
        :func:`~fiber_align.graph.endpoints.extra_publishers` when they change (``[]``:
        every topic has one publisher again).
    """

    def __init__(self, node, owners, on_change, period_s=PERIOD_S):
        """Start the thread and the delivery timer."""
        self._node, self._on_change, self.period_s = node, on_change, float(period_s)
        self.owners = {node.resolve_topic_name(t): o for t, o in owners.items()}
        self._rcl, self._ptr = Rcl(), node.handle.pointer
        self._found, self._told, self.checks = (), (), 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='fiber_align.owners',
                                        daemon=True)
        self._thread.start()
        self._timer = node.create_timer(self.period_s, self._deliver,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _count(self, topic):
        n = ctypes.c_size_t()
        if self._rcl.count_publishers(self._ptr, topic.encode(), ctypes.byref(n)):
            self._rcl.reset_error()
            return 0
        return n.value

    def _run(self):
        while not self._stop.wait(self.period_s):
            try:
                many = [t for t in self.owners if self._count(t) > 1]
                # the names (rclpy's query, the GIL held for it): only for such a topic
                pubs = {t: [node_fqn(i.node_name, i.node_namespace) for i in
                            self._node.get_publishers_info_by_topic(t)] for t in many}
            except Exception:  # noqa: BLE001 - the node is being destroyed
                return
            self._found = tuple(extra_publishers(self.owners, pubs))
            self.checks += 1

    def _deliver(self):
        found = self._found
        if found != self._told:
            self._told = found
            self._on_change(list(found))

    def close(self):
        """Stop the thread (before the node is destroyed) and the timer; return None."""
        self._stop.set()
        self._thread.join(2.0)
        self._node.destroy_timer(self._timer)
