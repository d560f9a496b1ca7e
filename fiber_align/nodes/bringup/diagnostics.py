# SPDX-License-Identifier: Apache-2.0
"""``bringup``'s view of ``/diagnostics``: each node's newest report and worst cycles."""

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from fiber_align.nodes._common import DIAG_QOS
from fiber_align.nodes._recording import diag_entry
from fiber_align.nodes.bringup.summary import worst_cycles


def spin_thread(executor):
    """Return a started daemon thread spinning ``executor`` until it is shut down."""
    def spin():
        try:
            executor.spin()
        except Exception:  # noqa: BLE001 - executor shut down at exit
            pass
    th = threading.Thread(target=spin, daemon=True)
    th.start()
    return th


#: s: the longest diagnostics period of a node of the graph (fiber_align.yaml: 0.5 s),
#: plus margin: the first report counted starts its window inside the run.
WINDOW_S = 0.6


class DiagnosticsWatch:
    """
    Keep the newest ``/diagnostics`` values of every node, on a node and thread of its own.

    The observer's executor may be seconds behind with samples (Python executor) when the
    stop needs fresh reports, hence a thread of its own.

    :ivar latest: node name -> its last key/value pairs (strings), ``level``, ``message``
        and ``_t`` (monotonic s of arrival).
    :ivar worst: node name -> its worst cycle window (:func:`summary.worst_cycles`).
    """

    def __init__(self, namespace):
        """Subscribe and start spinning (``namespace``: the graph's, or ``''``)."""
        self.latest = {}
        self.worst = {}
        #: monotonic s: reports of windows inside [run_from, run_to] count for ``worst``
        self.run_from = None
        self.run_to = None
        self.node = Node('bringup_diagnostics', namespace=namespace or None)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag,
                                      DIAG_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = spin_thread(self.executor)

    def _on_diag(self, msg):
        for st in msg.status:
            now = time.monotonic()
            node, values = diag_entry(st, now)
            self.latest[node] = values
            if self.in_run(now):
                worst_cycles(self.worst, node, self.latest[node])

    def in_run(self, t):
        """Return True when a report at ``t`` (monotonic s) covers run time only."""
        # a report covers the diagnostics period before it (0.5 s by default): the
        # first full window starts a period after the run did
        return self.run_from is not None and t >= self.run_from + WINDOW_S and (
            self.run_to is None or t <= self.run_to)

    def worst_windows(self):
        """Return node -> worst cycle window (a copy)."""
        return {n: dict(w) for n, w in self.worst.items()}

    def close(self):
        """Stop the executor and join the thread (it must leave rclpy before exit)."""
        self.executor.shutdown(timeout_sec=0.5)
        self.thread.join(timeout=2.0)
        self.node.destroy_node()
