# SPDX-License-Identifier: Apache-2.0
"""
``bringup``'s one orchestrator: spawn a described graph, observe it, stop it.

Every mode runs a graph of :mod:`fiber_align.graph` through :class:`Harness`, with the
description's processes, names, params and lifecycle (as the launch file); its bounds:
the ``bringup`` section of ``config/fiber_align.yaml``.
"""

import json
import os
from pathlib import Path
import signal
import sys
import tempfile
import time

from fiber_align.analysis import run_summary as sm
from fiber_align.analysis.recording import (recorder_counts, recorder_short, recorder_short_full,
                                            recorder_stopped)
from fiber_align.bringup import interrupt
from fiber_align.bringup.children import Child, wait_all
from fiber_align.bringup.floor import Floor
from fiber_align.bringup.observer import BadInput, BringupError, Observer
from fiber_align.graph.description import dds_environment
from fiber_align.graph.endpoints import (graph_names, node_fqn, surplus_publishers,
                                         unconnected)
from fiber_align.graph.params import effective, merge_params, PLANT, RECORDER, RUN_CATALOG
from fiber_align.jsonout import json_default
from fiber_align.nodes.ros.diagnostics import endpoint_node_name

EXIT_OK, EXIT_FAIL, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def settings(graph):
    """Return the ``bringup`` section of the graph's params files (bounds, s)."""
    return effective(merge_params(graph.params_files), 'bringup')


def _already_stopping(signum, frame):
    # os.write, not print: a handler that interrupted a print would re-enter its buffer
    os.write(1, b'bringup: already stopping (the stop is bounded by stop_timeout_s)\n')


def session(a, summary, steps, stop, errors=(BringupError,)):
    """
    Run ``steps()``, then ``stop(code)`` however it ended; return the exit code.

    The one way every mode ends: ``steps`` returns the code of a run that went through;
    an error (``errors``) is one line and ``summary['error']`` (exit 1; 2 for bad input),
    an interrupt exit 130 (``summary['interrupted']``); a signal during the stop is only
    noted. ``--strict``: missed realtime goals exit 1; ``--summary``: ``summary`` (JSON).
    """
    code = EXIT_FAIL
    try:
        code = steps()
    except KeyboardInterrupt:
        interrupt.handled()
        print('bringup: interrupted, stopping', flush=True)
        summary['interrupted'] = True
        code = EXIT_INTERRUPTED
    except errors as exc:
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
        summary['error'] = str(exc)
        code = EXIT_BAD_INPUT if isinstance(exc, (BadInput, ValueError)) else EXIT_FAIL
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _already_stopping)
        stop(code)
    if code == EXIT_OK and a.strict and summary.get('goals_missed'):
        print('bringup: --strict: %s' % '; '.join(summary['goals_missed']),
              file=sys.stderr, flush=True)
        code = EXIT_FAIL
    if a.summary:
        with open(a.summary, 'w', encoding='utf-8') as f:
            json.dump(summary, f, indent=1, sort_keys=True, default=json_default)
    return code


class Harness:
    """
    The processes of one graph and its observer: start, watch, stop in order.

    :param graph: a :class:`~fiber_align.graph.description.Graph` (or the rig's).
    :param observe: :class:`~fiber_align.bringup.observer.Observer` keyword
        arguments (``streams``, ``clock``, ...).
    :param endpoints: ``{topic: (publishers, subscribers)}`` to wait for (``{}``: none).
    """

    def __init__(self, graph, observe, quiet=True, endpoints=None):
        """Write the params file; nothing starts until :meth:`start`."""
        self.graph, self.observe, self.quiet = graph, observe, quiet
        self.gp = settings(graph)
        self.endpoints = endpoints or {}
        self.tmp = tempfile.TemporaryDirectory(prefix='fiber_align_bringup_')
        self.params = graph.write_params(os.path.join(self.tmp.name, 'params.yaml'))
        self.children, self.obs, self.summary = [], None, {}
        self.floor = None           # the machine-floor probe of a realtime run
        self._next_check, self.stopping = 0.0, False
        self.plants = tuple(n for n in graph.nodes if n.rsplit('/', 1)[-1] == PLANT)
        #: the recorded and sent counts when the recorder had matched every writer
        self.rec_base, self._rec_topics = None, None

    def start(self, ready=None):
        """Observe, spawn every process, wait for the nodes, the active drivers, the topics."""
        t0 = time.monotonic()
        g = self.graph
        timeout = float(self.gp['startup_timeout_s'])
        self.obs = Observer(g.namespace, **self.observe)
        self.obs.stall_s = float(self.gp['stall_timeout_s'])
        self.obs.call_s = float(self.gp['service_timeout_s'])
        self.obs.start_stall_s = float(self.gp['start_stall_timeout_s'])
        want = graph_names(g)
        env = dds_environment()
        # the recorder first: it is subscribed before the first sample is published
        for p in sorted(g.processes, key=lambda p: p.name != RECORDER):
            ch = Child(p.name, p.command(self.params, g.namespace, g.remappings,
                                         sys.executable), env, self.quiet)
            self.children.append(ch)
            print('bringup: started %s (pid %d)' % (p.name, ch.proc.pid), flush=True)
        self.obs.wait(lambda: want <= self.obs.node_names(), timeout, self.alive,
                      'every node on the graph')
        self.obs.wait(lambda: self.obs.active_nodes(g.managed_nodes, self.alive), timeout,
                      self.alive, 'the lifecycle nodes active (lifecycle_manager)')
        self.obs.wait(lambda: not unconnected(self.endpoints, self.obs.endpoint_counts(
            self.endpoints)), timeout, self.alive, 'topics connected: %s' % self.endpoints)
        if ready is not None:
            self.obs.wait(ready, timeout, self.alive, 'the graph ready')
        self.alive()
        self.summary['startup_s'] = time.monotonic() - t0
        for ch in self.children:
            ch.mark()

    def alive(self):
        """Raise when a process exited or another graph publishes on the topics."""
        interrupt.check()
        for ch in self.children:
            if not ch.alive():
                ch.thread.join(timeout=1.0)
                if ch.proc.returncode == 2:
                    raise BadInput(ch.last_error or '%s refused its parameters' % ch.name)
                raise BringupError('%s exited with code %s%s' % (
                    ch.name, ch.proc.returncode, (': ' + ch.last_error) if ch.last_error
                    else ''))
        now = time.monotonic()
        if self.endpoints and self.obs is not None and now >= self._next_check:
            self._next_check = now + 1.0
            extra = surplus_publishers(self.endpoints, self.obs.endpoint_counts(self.endpoints))
            if extra:
                raise BringupError(
                    'another graph shares ROS_DOMAIN_ID=%s: %s; run on a domain of its own'
                    % (os.environ.get('ROS_DOMAIN_ID', '0'), ', '.join(extra)))

    def run(self, on=True, timeout_s=None):
        """Start (or hold) every plant's sample clock (``<plant>/run``; ``timeout_s`` s)."""
        from std_srvs.srv import SetBool
        if on and self.graph.record:
            if getattr(self.graph, 'axes', None):
                self.rec_base = self._recorder_base()
            else:
                self._recorder_matched()
        # all at once: a driver whose plant is held while the others run trips its watchdog
        self.obs.call_all([(self.obs.client(SetBool, p + '/run'), SetBool.Request(data=on))
                           for p in self.plants], timeout_s or self.obs.call_s, self.alive)
        if on and self.floor is None and self.plants and self.graph.sync_mode == 'realtime' \
                and self.gp['machine_floor']:
            plant = self.graph.node_params(self.plants[0])
            self.floor = Floor(plant['rate_hz'], plant['realtime_priority'], self.tmp.name)
            print('bringup: started machine_floor (pid %d)' % self.floor.proc.pid, flush=True)

    @property
    def cycle_goal(self):
        """Return the share of missed periods a run is held to (the plant's parameter)."""
        return float(self.graph.node_params(self.plants[0])['cycle_goal_missed_share']) \
            if self.plants else 0.0

    def floor_figures(self):
        """Stop the machine-floor probe of the run; return its figures (``None``: none)."""
        return self.floor.stop() if self.floor is not None else None

    @property
    def full_nodes(self):
        """Return the full name of every node of the graph (``/station/in/x/...``)."""
        return [node_fqn(n, ns) for n, ns in graph_names(self.graph)]

    def recorder_reads(self):
        """Return True when the recorder (if any) reads every writer of its topics."""
        g, node = self.graph, self.obs.node
        if not g.record:
            return True
        if self._rec_topics is None:
            # the topics it reads in-process (hosted in the composed process) need no match
            host = self._recorder_host()
            local = set(host.local_topics(g.namespace)) if host is not None else set()
            self._rec_topics = [t for t in (node.resolve_topic_name(t) for t in g.node_params(
                RECORDER)['topics']) if t not in local]
        rec = node_fqn(RECORDER, '/' + g.namespace)
        return all(not node.count_publishers(t) or any(
            endpoint_node_name(i) == rec for i in node.get_subscriptions_info_by_topic(t))
            for t in self._rec_topics)

    def _recorder_matched(self):
        """Wait until the recorder reads every writer of its topics (bounded)."""
        self.obs.wait(self.recorder_reads, float(self.gp['startup_timeout_s']), self.alive,
                      'the recorder on every recorded topic')
        # this node saw the recorder's readers; each writer matches them on its own, a
        # little later (a first sample sent before that reaches no reader)
        time.sleep(float(self.gp['recorder_match_s']))

    def _recorder_base(self):
        """
        Wait until the recorder reads every writer of its topics; return the counts then.

        The multi-axis graphs: a volatile message sent before the recorder matched its
        writer (an activation, the sequencer's first setpoints) reaches no late reader, so
        "every message in the bag" counts from here (the plants are still held: nothing
        is published between this count and their start).
        """
        self._recorder_matched()
        timeout = float(self.gp['startup_timeout_s'])
        t0 = time.monotonic()
        diag = self.obs.watch.by_status['latest']
        self.obs.wait(lambda: recorder_counts(diag, self.full_nodes, t0) is not None,
                      timeout, self.alive, 'fresh counts of the recorder and every node')
        return recorder_counts(diag, self.full_nodes, t0)

    def stop(self, interrupted=False):
        """Hold the plants, SIGINT the nodes, then the recorder, within stop_timeout_s."""
        if self.stopping:
            return self.summary
        self.stopping = True
        t_stop = time.monotonic()
        deadline = t_stop + max(1.0, float(self.gp['stop_timeout_s']) - 0.5)
        s = self.summary
        if self.children:
            s['processes'] = {ch.name: ch.usage() for ch in self.children}
        # the run's own realtime figures: the plants held below may trip the watchdogs
        latest = self.obs.watch.latest if self.obs is not None else {}
        s['realtime'] = sm.realtime_figures(latest)
        if self.floor is not None:
            s['floor'] = self.floor_figures()
        s['cycles'] = {n: dict(w) for n, w in self.obs.watch.worst.items()} if self.obs else {}
        host = self._recorder_host()
        # the recorder's process: its own (stopped after the others) or the composed one
        rec = [ch for ch in self.children if host is not None and ch.name == host.name]
        separate = bool(rec) and host.name == RECORDER
        # the catalogue last: it links the snapshots the recorder writes at its close
        last = [ch for ch in self.children if ch.name == RUN_CATALOG]
        nodes = [ch for ch in self.children if not (separate and ch in rec or ch in last)]
        if self.obs is not None:
            self.obs.active = False
            if self.plants and all(ch.alive() for ch in nodes):
                try:
                    self.run(False, 0.5)    # best effort: the stop goes on regardless
                except BringupError:
                    pass
            time.sleep(0.1)   # in-flight messages reach their subscribers
        stopped = recorder_stopped(self.obs.watch.by_status['latest']) if self.obs else None
        if stopped:                     # a full disk: the run went on, its bag ends early
            s['recording_stopped_early'] = stopped
            if self.quiet:              # else the recorder's own line was relayed
                print('bringup: %s' % stopped, flush=True)
        if rec and rec[0].alive() and self.obs is not None and self.graph.record:
            # held: the recorder drains before the publishers go (an exiting writer takes
            # its undelivered samples along); a snapshots-only recorder has no bag to wait on
            limit = (deadline - 2.5 - time.monotonic()) if interrupted else 30.0
            waited, short = self._wait_recorder(latest, rec[0], max(0.5, limit))
            s['recorder_catch_up_s'] = waited
            if short:
                s['recorder_short'] = {k: list(v) for k, v in short.items()}
        for ch in nodes:
            ch.interrupt()
        wait_all(nodes, deadline - (1.5 if separate else 0.0) - time.monotonic())
        for ch in (rec if separate else []) + last:
            ch.interrupt()
            # at least 4 s: the recorder drains while the graph still publishes, then
            # closes the bag; a SIGKILL before that leaves it without metadata
            ch.wait(max(deadline - time.monotonic(), 4.0))
        s['sent'] = {node: sent for ch in self.children for node, sent in ch.sent.items()}
        s['children'] = {ch.name: {'pid': ch.proc.pid, 'exit_code': ch.proc.returncode,
                                   'stop_s': ch.stop_s, 'last_error': ch.last_error}
                         for ch in self.children}
        s['stop_s'] = time.monotonic() - t_stop
        counts = Path(self.graph.record or '/nonexistent') / 'recorder_counts.json'
        if counts.is_file():
            s['recorded'] = json.loads(counts.read_text(encoding='utf-8'))
        return s

    def _recorder_host(self):
        """Return the process that hosts the recorder (its own, or composed), or None."""
        return next((p for p in self.graph.processes
                     if any(b == RECORDER for b, _ in p.hosted(self.graph.namespace))), None)

    def _wait_recorder(self, diag, ch, limit_s):
        """
        Wait until the recorder holds every message the nodes sent; return (s waited, short).

        The rule is :func:`fiber_align.analysis.recording.recorder_short`; only reports made
        after the plant was held count. Reliable delivery may need a retransmission after
        a burst, so the wait is on the counts themselves, bounded by ``limit_s`` (s).
        ``short``: topic -> (recorded, sent) left.
        """
        t0 = time.monotonic()
        short = None
        while time.monotonic() - t0 < limit_s and ch.alive():
            time.sleep(0.05)
            if getattr(self.graph, 'axes', None):       # the rig, the station
                now = recorder_short_full(self.obs.watch.by_status['latest'], t0,
                                          self.full_nodes, self.rec_base)
            else:
                now = recorder_short(diag, t0, self.graph.nodes)
            if now is not None:
                short = now
                if not short:
                    break
        return time.monotonic() - t0, short or {}

    def close(self):
        """Destroy the observer (its threads leave rclpy first) and the params file."""
        self.floor_figures()
        if self.obs is not None:
            self.obs.destroy()
            self.obs = None
        self.tmp.cleanup()
