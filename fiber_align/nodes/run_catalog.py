# SPDX-License-Identifier: Apache-2.0
"""
``run_catalog``: the graph's run and its alignments written into the run catalogue.

A process of its own (never inside ``control_graph``: the catalogue's writes, and a
database that is locked, full or unreachable, must cost no control period). Relative
names, SI units (docs/records.md):

- sub ``alignment_state`` (std_msgs/String, the sequencer's JSON status, with its
  ``part_id``), ``optical_power`` (std_msgs/Float64, W), ``/diagnostics`` (the plants'
  cycles kept, the drivers' watchdog trips);
- writes the ``runs`` row at its start and again, with its end figures, at its stop, and
  an ``alignments`` row per alignment (:class:`fiber_align.alignment.record.AlignmentLog`)
  through :class:`fiber_align.records.writer.CatalogWriter` (its own thread, a bounded
  queue, a spool);
- ``/diagnostics``: OK while rows reach the catalogue, WARN while they spool, with the
  reason (one line, also logged once per new reason).

Parameters: ``config/records.yaml`` (the catalogue, the writer's timing, what the graph
description sets: ``machine``, ``hardware``, ``bag_path``, ``graph_parameters``).
"""

import json
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_msgs.msg import Float64, String

from fiber_align.alignment.record import AlignmentLog, RunTally
from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.diagnostics import Health, OK, WARN
from fiber_align.nodes.ros.params import declare, declare_graph_values, node_defaults
from fiber_align.nodes.ros.qos import DIAG_QOS, REALTIME_QOS, STATE_LOG_QOS
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.nodes.ros.teardown import say
from fiber_align.records import rows
from fiber_align.records.writer import CatalogWriter

SPEC = NODES['run_catalog']
#: The writer's parameters (config/records.yaml): name -> (description, lo, hi).
WRITER = {'catalog': ('the catalogue: default, none, a SQLite path or postgresql://... '
                      '(docs/records.md)', None, None),
          'queue_size': ('rows waiting for the writer thread at most', 1, 10 ** 7),
          'retry_period_s': ('how often the writer tries the catalogue again (s)',
                             0.01, 3600.0),
          'connect_timeout_s': ('a PostgreSQL connection attempt at most (s)', 0.01, 600.0),
          'busy_timeout_s': ('a wait for a locked SQLite file at most (s)', 0.0, 600.0),
          'spool_dir': ("the spool folder ('' = $ROS_HOME/fiber_align/spool)", None, None)}
#: The run's parameters the graph description sets (config/records.yaml).
RUN = {'machine': ('the machine: 1d, rig, station', None, None),
       'hardware': ('the graph drives real devices', None, None),
       'bag_path': ("the bag the run records into ('' = none)", None, None),
       'graph_parameters': ("every node's parameters, JSON ('' = none)", None, None),
       'reference_power_w': ('the power of a loss of 0 dB (W); 0: no loss figure',
                             0.0, 1e3)}
#: s to write the last rows at the stop (the teardown's bound is longer).
CLOSE_S = 3.0
#: At the stop, the statuses already on their way are still taken: until none came for
#: ``QUIET_S`` (s), ``DRAIN_S`` (s) at most (a graph stopped right after a state change).
QUIET_S, DRAIN_S = 0.2, 1.0


class RunCatalogNode(Node):
    """The run's and its alignments' rows from the graph's topics, off the control path."""

    def __init__(self, **kwargs):
        """Declare the parameters, start the writer, write the run's first row, subscribe."""
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        p = {k: declare(self, d, k, text, lo, hi, True)
             for k, (text, lo, hi) in dict(WRITER, **RUN).items()}
        g = declare_graph_values(self, d, 'sync_mode', 'rate_hz', 'diagnostics_period_s')
        self.p, self.sync_mode = p, g['sync_mode']
        self.writer = CatalogWriter(p['catalog'], p)
        self.run_id = rows.new_run_id()
        self.started_at = rows.stamp()
        self.log = AlignmentLog(self.run_id, p['reference_power_w'] or None,
                                1.0 / float(g['rate_hz']))
        self.tally, self.state, self.closed, self.n_rows = RunTally(), None, False, 0
        self.n_status = 0
        self._put('runs', self._run_row())
        self.create_subscription(String, 'alignment_state', self._on_state, STATE_LOG_QOS)
        self.create_subscription(Float64, 'optical_power',
                                 lambda msg: self.log.on_power(float(msg.data)),
                                 REALTIME_QOS)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, DIAG_QOS)
        self.health = Health(self, g['diagnostics_period_s'], update=self._report)
        self._said = ''
        self._report()
        self.get_logger().info('run %s into the catalogue %s' % (self.run_id,
                                                                 self.writer.name))

    def _run_row(self, **end):
        p = self.p
        try:
            params = json.loads(p['graph_parameters']) if p['graph_parameters'] else None
        except ValueError:
            params = None
        return rows.run_row(self.run_id, p['machine'] or None, self.sync_mode, p['hardware'],
                            params, self.started_at, bag_path=p['bag_path'] or None, **end)

    def _put(self, table, row):
        self.writer.put(table, row)
        self.n_rows += 1

    def _on_state(self, msg):
        self.n_status += 1
        try:
            status = json.loads(msg.data)
        except ValueError:
            return
        self.state = status.get('state', self.state)
        for row in self.log.on_status(status):
            self._put('alignments', row)

    def _on_diag(self, msg):
        for s in msg.status:
            self.tally.on_status(s.name, {kv.key: kv.value for kv in s.values})

    def _report(self, *_):
        """Put the writer's state on ``/diagnostics``; log a new reason once."""
        st = self.writer.state()
        spooling = st['level'] == 'spooling'
        self.health.summary(WARN if spooling else OK, st['reason'] if spooling else
                            'run %s: %s' % (self.run_id, st['level']))
        self.health.set_values(run_id=self.run_id, catalog=self.writer.name,
                               **{k: st[k] for k in ('queued', 'spooled', 'written',
                                                     'dropped')})
        if spooling and st['reason'] != self._said:
            self.get_logger().warning('%s: rows wait in %s' % (st['reason'],
                                                               self.writer.spool))
        self._said = st['reason'] if spooling else ''

    def close(self):
        """At the stop: the open alignment's row, the run's end figures, the last writes."""
        if self.closed:
            return
        self.closed = True
        for row in self.log.close():
            self._put('alignments', row)
        self._put('runs', self._run_row(ended_at=rows.stamp(), end_reason='stopped; '
                                        'sequencer %s' % (self.state or 'not seen'),
                                        **self.tally.figures()))
        # a catalogue that already spools gets no wait: its rows are in the spool file
        done = self.writer.state()['level'] == 'ok' and self.writer.flush(CLOSE_S)
        st = self.writer.state()
        self.writer.close(0.5)
        say('run_catalog: run %s, %d alignments: %s' % (
            self.run_id, self.log.seq, 'written to %s' % self.writer.name if done and
            st['level'] == 'ok' else '%s; %d rows wait in %s' % (
                st['reason'] or 'not all written', st['spooled'] + st['queued'],
                self.writer.spool)))

    def sent_counts(self):
        """Return the rows put into the writer (the node publishes no topic)."""
        return {'catalog_rows': self.n_rows}


def _drain(executor, node):
    """Take the statuses already on their way once the spin ended (see :data:`QUIET_S`)."""
    t0 = quiet = time.monotonic()
    last = node.n_status
    while time.monotonic() - t0 < DRAIN_S and time.monotonic() - quiet < QUIET_S:
        executor.spin_once(timeout_sec=0.02)
        if node.n_status != last:
            last, quiet = node.n_status, time.monotonic()


def main(args=None):
    """Run the node (bad parameters: one line, exit 2); the last statuses are taken."""
    return run_node(RunCatalogNode, SPEC.node, args, realtime=lambda node: False,
                    then=_drain)


if __name__ == '__main__':
    sys.exit(main())
