# SPDX-License-Identifier: Apache-2.0
"""``bringup``'s view of ``/diagnostics``: each node's newest report and worst cycles."""

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from fiber_align.nodes._common import DIAG_QOS
from fiber_align.nodes.bringup.summary import worst_cycles


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
        self.node = Node('bringup_diagnostics', namespace=namespace or None)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag,
                                      DIAG_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on_diag(self, msg):
        for st in msg.status:
            lvl = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
            node = st.name.rsplit('/', 1)[-1]
            vals = {kv.key: kv.value for kv in st.values}
            self.latest[node] = {'level': lvl, 'message': st.message,
                                 '_t': time.monotonic(), **vals}
            worst_cycles(self.worst, node, self.latest[node])

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - executor shut down at exit
            pass

    def worst_windows(self):
        """Return node -> worst cycle window, without bookkeeping keys."""
        return {n: {k: v for k, v in w.items() if not k.startswith('_')}
                for n, w in self.worst.items()}

    def close(self):
        """Stop the executor and join the thread (it must leave rclpy before exit)."""
        self.executor.shutdown(timeout_sec=0.5)
        self.thread.join(timeout=2.0)
        self.node.destroy_node()
