# SPDX-License-Identifier: Apache-2.0
"""
``run_catalog``: the graph's run and its alignments written into the run catalogue.

Its own process (a locked, full or unreachable database costs no control period). Sub
``alignment_state`` (the sequencer's JSON status: ``part_id``, power, peak; no 1 kHz topic),
``/diagnostics`` (cycles kept, trips: raw, decoded only when a plant's or a driver's),
``snapshot_written``; rows through a :class:`~fiber_align.records.writer.CatalogWriter`;
``/diagnostics``: OK, WARN while they spool (logged once). docs/records.md.
"""

import sys

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_msgs.msg import String

from fiber_align.alignment.record import RunRecord
from fiber_align.graph.ranges import CATALOG_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.lifeline import say
from fiber_align.nodes.ros.diagnostics import Health, OK, WARN
from fiber_align.nodes.ros.params import declare, declare_graph_values, node_defaults
from fiber_align.nodes.ros.qos import DIAG_QOS, STATE_QOS
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.nodes.ros.teardown import spin_until_quiet
from fiber_align.records.writer import CatalogWriter

SPEC = NODES['run_catalog']
PARAMS = CATALOG_RANGES
#: s to write the last rows at the stop; at the stop the statuses on their way are still
#: taken until none came for QUIET_S (s), DRAIN_S (s) at most.
CLOSE_S, QUIET_S, DRAIN_S = 3.0, 0.2, 1.0


class RunCatalogNode(Node):
    """The run's and its alignments' rows from the graph's topics, off the control path."""

    def __init__(self, **kwargs):
        """Declare the parameters, start the writer, put the run's first row, subscribe."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        p = {k: declare(self, d, k, t, lo, hi, True) for k, (t, lo, hi) in PARAMS.items()}
        g = declare_graph_values(self, d, 'sync_mode', 'rate_hz', 'diagnostics_period_s')
        self.writer = CatalogWriter(p['catalog'], p)
        self.rec = RunRecord(dict(p, sync_mode=g['sync_mode']), 1.0 / float(g['rate_hz']))
        self.closed, self.n_rows, self.n_status, self._said = False, 0, 0, ''
        self._put('runs', self.rec.start_row())
        self.create_subscription(String, 'alignment_state', self._on_state, STATE_QOS)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                 DIAG_QOS, raw=True)
        self.create_subscription(String, 'snapshot_written', lambda msg: self._put(
            'runs', self.rec.on_snapshot(msg.data)), STATE_QOS)
        self.health = Health(self, g['diagnostics_period_s'], update=self._report)
        self._report()
        self.get_logger().info('run %s into the catalogue %s' % (self.rec.run_id,
                                                                 self.writer.name))

    def _put(self, table, row):
        self.writer.put(table, row)
        self.n_rows += 1

    def _on_diagnostics(self, data):
        if b'sim_time_s' in data or b'watchdog_count' in data:   # a plant's or a driver's
            for s in deserialize_message(data, DiagnosticArray).status:
                self.rec.tally.on_status(s.name, {kv.key: kv.value for kv in s.values})

    def _on_state(self, msg):
        self.n_status += 1
        for row in self.rec.on_status(msg.data):
            self._put('alignments', row)

    def _report(self, *_):
        """Put the writer's state on ``/diagnostics``; log a new reason once."""
        st = self.writer.state()
        spooling = st['level'] == 'spooling'
        self.health.summary(WARN if spooling else OK, st['reason'] if spooling else
                            'run %s: %s' % (self.rec.run_id, st['level']))
        self.health.set_values(run_id=self.rec.run_id, catalog=self.writer.name, **{
            k: st[k] for k in ('queued', 'spooled', 'written', 'dropped')})
        if spooling and st['reason'] != self._said:
            self.get_logger().warning('%s: rows wait in %s' % (st['reason'],
                                                               self.writer.spool))
        self._said = st['reason'] if spooling else ''

    def close(self):
        """At the stop: the open alignment's row, the run's end figures, the last writes."""
        if self.closed:
            return
        self.closed = True
        for table, row in self.rec.end_rows():
            self._put(table, row)
        # a catalogue that already spools gets no wait: its rows are in the spool file
        done = self.writer.state()['level'] == 'ok' and self.writer.flush(CLOSE_S)
        st = self.writer.close(0.5)
        say('run_catalog: run %s, %d alignments: %s' % (
            self.rec.run_id, self.rec.log.seq, 'written to %s' % self.writer.name
            if done and st['level'] == 'ok' else '%s; %d rows wait in %s' % (
                st['reason'] or 'not all written', st['spooled'] + st['queued'],
                self.writer.spool)))


def main(args=None):
    """Run the node (bad parameters: one line, exit 2); the last statuses are taken."""
    return run_node(RunCatalogNode, SPEC.node, args, realtime=lambda node: True,
                    then=lambda ex, node: spin_until_quiet(
                        ex, lambda: node.n_status, QUIET_S, DRAIN_S))


if __name__ == '__main__':
    sys.exit(main())
