# SPDX-License-Identifier: Apache-2.0
"""
``bringup``'s one orchestrator: spawn a described graph, observe it, stop it, summarise.

Every mode (the 1-D graph, ``--rig``, ``--hardware``) runs a graph of
:mod:`fiber_align.graph` through :class:`Harness`: the processes, node names, params
and lifecycle are the description's (``Process.command`` and ``Graph.write_params``, as
the launch file); ``lifecycle_manager`` activates the lifecycle nodes and the harness only
waits for them. Its bounds are the ``bringup`` section of ``config/fiber_align.yaml``.
"""

import json
import os
from pathlib import Path
import signal
import sys
import tempfile
import time

import numpy as np

from fiber_align.analysis import run_summary as sm
from fiber_align.analysis.report import hysteresis_metrics
from fiber_align.graph.description import dds_environment
from fiber_align.graph.params import effective, merge_params, PLANT, RECORDER, SCENARIO_RUNNER
from fiber_align.graph.registry import expected_endpoints
from fiber_align.jsonout import json_default
from fiber_align.nodes._recording import recorder_counts, recorder_short, recorder_short_full
from fiber_align.bringup import interrupt
from fiber_align.bringup.children import Child, wait_all
from fiber_align.bringup.cli import TRACKING_SCENARIOS
from fiber_align.bringup.observer import BadInput, BringupError, Observer, StartStall
from fiber_align.bringup.floor import Floor
from fiber_align.nodes.ros.diagnostics import endpoint_node_name

EXIT_OK, EXIT_FAIL, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def settings(graph):
    """Return the ``bringup`` section of the graph's params files (bounds, s)."""
    return effective(merge_params(graph.params_files), 'bringup')


def _already_stopping(signum, frame):
    # os.write, not print: a handler that interrupted a print would re-enter its buffer
    os.write(1, b'bringup: already stopping (the stop is bounded by stop_timeout_s)\n')


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
        self.rec_base = None

    def start(self, check_alone=True, ready=None):
        """Observe, spawn every process, wait for the nodes, the active drivers, the topics."""
        t0 = time.monotonic()
        g = self.graph
        timeout = float(self.gp['startup_timeout_s'])
        self.obs = Observer(g.namespace, **self.observe)
        self.obs.stall_s = float(self.gp['stall_timeout_s'])
        self.obs.start_stall_s = float(self.gp['start_stall_timeout_s'])
        want = set()
        for p in g.processes:
            want.update(p.hosted(g.namespace))
        if check_alone:
            time.sleep(float(self.gp['discovery_wait_s']))
            others = sorted(n for n, ns in want & self.obs.node_names())
            if others:
                raise BringupError(
                    'another fiber_align graph runs on ROS_DOMAIN_ID=%s in namespace /%s '
                    '(its nodes: %s); stop it, or use --namespace or another ROS_DOMAIN_ID'
                    % (os.environ.get('ROS_DOMAIN_ID', '0'), g.namespace, ', '.join(others)))
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
        self.obs.wait(lambda: not self.obs.short_endpoints(self.endpoints), timeout,
                      self.alive, 'topics connected: %s' % self.endpoints)
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
            extra = self.obs.foreign_publishers(self.endpoints)
            if extra:
                raise BringupError(
                    'another graph shares ROS_DOMAIN_ID=%s: %s; run on a domain of its own'
                    % (os.environ.get('ROS_DOMAIN_ID', '0'), ', '.join(extra)))

    def run(self, on=True):
        """Start (or hold) every plant's sample clock (``<plant>/run``)."""
        from std_srvs.srv import SetBool
        if on and self.graph.record and getattr(self.graph, 'axes', None):
            self.rec_base = self._recorder_base()
        for p in self.plants:
            self.obs.call(self.obs.client(SetBool, p + '/run'), SetBool.Request(data=on),
                          5.0 if on else 0.5, self.alive)
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
        return ['%s/%s' % (ns.rstrip('/'), n) for p in self.graph.processes
                for n, ns in p.hosted(self.graph.namespace)]

    def _recorder_base(self):
        """
        Wait until the recorder reads every writer of its topics; return the counts then.

        The multi-axis graphs: a volatile message sent before the recorder matched its
        writer (an activation, the sequencer's first setpoints) reaches no late reader, so
        "every message in the bag" counts from here (the plants are still held: nothing
        is published between this count and their start).
        """
        g, node = self.graph, self.obs.node
        rec = '/%s/%s' % (g.namespace, RECORDER) if g.namespace else '/' + RECORDER
        # the topics it reads in-process (hosted in the composed process) need no match
        host = self._recorder_host()
        local = set(host.local_topics(g.namespace)) if host is not None else set()
        topics = [t for t in (node.resolve_topic_name(t)
                              for t in g.node_params(RECORDER)['topics']) if t not in local]

        def matched():
            return all(not node.count_publishers(t) or any(
                endpoint_node_name(i) == rec for i in node.get_subscriptions_info_by_topic(t))
                for t in topics)
        timeout = float(self.gp['startup_timeout_s'])
        self.obs.wait(matched, timeout, self.alive, 'the recorder on every recorded topic')
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
        # the realtime figures of the run itself: holding the plant below stops the
        # loop's input, which the driver's watchdog then reports as a trip
        latest = self.obs.watch.latest if self.obs is not None else {}
        s['realtime'] = sm.realtime_figures(latest)
        floor = self.floor_figures()
        if floor is not None:
            s['floor'] = floor
        s['cycles'] = {n: dict(w) for n, w in self.obs.watch.worst.items()} if self.obs else {}
        host = self._recorder_host()
        # the recorder's process: its own (stopped after the others) or the composed one
        rec = [ch for ch in self.children if host is not None and ch.name == host.name]
        separate = bool(rec) and host.name == RECORDER
        nodes = [ch for ch in self.children if not (separate and ch in rec)]
        if self.obs is not None:
            self.obs.active = False
            if self.plants and all(ch.alive() for ch in nodes):
                try:
                    self.run(False)
                except BringupError:
                    pass
            time.sleep(0.1)   # in-flight messages reach their subscribers
        if rec and rec[0].alive() and self.obs is not None:
            # the graph is held: the recorder works through its backlog before the
            # publishers go (a writer that exits takes its undelivered samples with it)
            limit = (deadline - 2.5 - time.monotonic()) if interrupted else 30.0
            waited, short = self._wait_recorder(latest, rec[0], max(0.5, limit))
            s['recorder_catch_up_s'] = waited
            if short:
                s['recorder_short'] = {k: list(v) for k, v in short.items()}
        for ch in nodes:
            ch.interrupt()
        wait_all(nodes, deadline - (1.5 if separate else 0.0) - time.monotonic())
        for ch in (rec if separate else ()):
            ch.interrupt()
            # at least 4 s: the recorder drains while the graph still publishes, then
            # closes the bag; a SIGKILL before that leaves it without metadata
            ch.wait(max(deadline - time.monotonic(), 4.0))
        for ch in self.children:
            s.setdefault('sent', {}).update(ch.sent)
        s['children'] = {ch.name: {'pid': ch.proc.pid, 'exit_code': ch.proc.returncode,
                                   'stop_s': ch.stop_s}
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

        The rule is :func:`fiber_align.nodes._recording.recorder_short`; only reports made
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


class Bringup:
    """The 1-D graph: run its scenario on a :class:`Harness`, retry a stalled start."""

    def __init__(self, args, graph, source):
        """Keep the options, the graph and the scenario's source (``None``: none)."""
        self.args, self.graph, self.source = args, graph, source
        self.scenario, self.sync = graph.scenario, graph.sync_mode
        self.rate = float(graph.node_params(PLANT)['rate_hz'])
        self.duration = float(graph.node_params(SCENARIO_RUNNER).get('duration_s', 0.0)) \
            if source is not None else float('inf')
        self.cycles = args.cycles if args.cycles is not None else int(
            settings(graph)['switch_cycles'])
        self.summary, self.h = {}, None

    def _harness(self):
        streams = {'y': 'displacement', 'v': 'drive_voltage'}
        if self.source is None:
            streams.update(r_ref='reference', p='optical_power')
        recorded = self.graph.node_params(RECORDER).get('topics', ()) \
            if self.graph.record else ()
        want = expected_endpoints(self.graph, tuple(streams.values()) + (
            ('alignment_state',) if self.source is None else ()), recorded)
        return Harness(self.graph, dict(streams=streams, clock='y', source=self.source,
                                        lockstep=self.sync == 'lockstep', rate_hz=self.rate,
                                        duration_s=self.duration),
                       self.args.quiet, want)

    def run(self):
        """Run the whole bring-up; return the exit code."""
        code = EXIT_OK
        retries = int(settings(self.graph)['start_retries'])
        try:
            for attempt in range(retries + 1):
                self.h = self._harness()
                try:
                    self.h.start(check_alone=attempt == 0)
                    print('bringup: graph up in %.2f s (%s, %g Hz, %s, %s)' % (
                        self.h.summary['startup_s'], self.sync, self.rate,
                        self.graph.controller, 'composed' if self.graph.composed
                        else 'multi-process'), flush=True)
                    self._run_scenario()
                    break
                except StartStall as exc:
                    if attempt == retries:
                        raise
                    print('bringup: %s; restarting the graph (restart %d, counted in the '
                          'summary)' % (exc, attempt + 1), flush=True)
                    self.h.stop()
                    self.h.close()
                    self.summary['restarts'] = attempt + 1
                    if self.graph.record and os.path.isdir(self.graph.record):
                        import shutil
                        shutil.rmtree(self.graph.record)
        except KeyboardInterrupt:
            interrupt.handled()
            print('bringup: interrupted, stopping', flush=True)
            code = EXIT_INTERRUPTED
            self.summary['interrupted'] = True
        except BringupError as exc:
            print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
            self.summary['error'] = str(exc)
            code = EXIT_BAD_INPUT if isinstance(exc, BadInput) else EXIT_FAIL
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, _already_stopping)
            if self.h is not None:
                self.summary.update(self.h.stop(code == EXIT_INTERRUPTED))
                self._report()
                self.h.close()
        if code == EXIT_OK and self.args.strict and self.summary.get('goals_missed'):
            print('bringup: --strict: %s' % '; '.join(self.summary['goals_missed']),
                  file=sys.stderr, flush=True)
            code = EXIT_FAIL
        return code

    def _run_scenario(self):
        h, r = self.h, self.h.obs
        t0 = time.monotonic()
        r.start()
        h.run(True)
        if self.scenario == 'none':
            print('bringup: running; publish `setpoint` (m). Ctrl-C stops.', flush=True)
            while True:
                h.alive()
                time.sleep(0.1)
        try:
            if self.scenario == 'align':
                self.summary['align_events'] = self._align()
                return
            wall_limit = 60.0 + 20.0 * self.duration
            drain_s = float(h.gp['observer_drain_s'])
            while not r.done.wait(0.02):
                h.alive()
                r.check_stall()
                if r.behind(drain_s):
                    # the graph's run is over; this observer's record ends short of it
                    # (its sample count says how short)
                    print('bringup: the scenario ended %.1f s ago and this observer is '
                          'behind its streams (%d samples read): stopping'
                          % (time.monotonic() - r.runner_done_at, r.samples), flush=True)
                    self.summary['observer_behind'] = True
                    break
                if time.monotonic() - t0 > wall_limit:
                    raise BringupError('scenario did not finish within %g s' % wall_limit)
        finally:
            self.summary['run_wall_s'] = time.monotonic() - t0
            r.watch.run_to = time.monotonic()

    def _align(self):
        """
        Align, hold, run ``self.cycles`` switch cycles; return the events (sample indices).

        Waits count samples (sample time), each bounded in wall time.

        :raises BringupError: a refused call, a FAULT, a timeout.
        """
        from std_srvs.srv import SetBool, Trigger
        r, alive = self.h.obs, self.h.alive

        def k(seconds):
            return int(round(seconds * self.rate))

        def call(srv, name, request, what):
            n = len(r.states)
            res = r.call(r.client(srv, name), request, 10.0)
            if not res.success:
                raise BringupError('%s refused: %s' % (what, res.message))
            return r.event(n)

        def ended(events, what):
            st = r.status
            self.summary['align_events'] = events
            raise BringupError('%s ended in %s: %s' % (
                what, st.get('state'), st.get('fault_reason') or 'timeout'))

        wall = 30.0 + 40.0 * (sm.ALIGN_MAX_S + self.cycles * (sm.SWITCH_OFF_S
                                                              + sm.SWITCH_ON_S))
        r.wait_samples(k(sm.ALIGN_IDLE_S), wall, alive)
        events = {'align': call(Trigger, 'align', Trigger.Request(), 'align')}
        r.wait_samples(events['align'] + k(sm.ALIGN_MAX_S), wall, alive,
                       lambda: r.status.get('state') in ('TRACKING', 'FAULT'))
        if r.status.get('state') != 'TRACKING':
            ended(events, 'alignment')
        k_tracking = r.first('TRACKING', events['align'])[0]
        events['tracking'] = r.samples if k_tracking is None else k_tracking
        r.wait_samples(events['tracking'] + k(sm.LOSS_WINDOW_S), wall, alive)
        events['cycles'] = []
        for _ in range(self.cycles):
            k_off = call(SetBool, 'switch', SetBool.Request(data=False), 'switch off')
            r.wait_samples(k_off + k(sm.SWITCH_OFF_S), wall, alive)
            k_on = call(SetBool, 'switch', SetBool.Request(data=True), 'switch on')
            r.wait_samples(k_on + k(sm.SWITCH_ON_S), wall, alive)
            events['cycles'].append((k_off, k_on, r.samples))
            if r.status.get('state') == 'FAULT':
                break
        if r.status.get('state') != 'TRACKING':
            ended(events, 'switch cycles')
        return events

    def _report(self):
        s, a, g = self.summary, self.args, self.graph
        s.update({'scenario': self.scenario, 'sync_mode': self.sync, 'rate_hz': self.rate,
                  'controller': g.controller, 'composed': g.composed,
                  'namespace': g.namespace, 'record': g.record or None,
                  'model_file': os.path.abspath(a.model) if a.model else None})
        r = self.h.obs
        if r is not None:
            t, ref, y = r.trace()
            if self.source is None:
                ref = r.series('r_ref')
            s['samples'] = int(t.size)
            if t.size > 2 and self.scenario in TRACKING_SCENARIOS:
                s['metrics'] = sm.scenario_metrics(self.scenario, t, ref, y, r.series('v'))
            elif t.size > 2 and self.scenario == 'hysteresis-experiment':
                s['metrics'] = hysteresis_metrics(r.series('v'), y)
            elif t.size > 2 and self.scenario == 'align':
                s['align'] = sm.align_metrics(t, y, r.series('p'), r.states,
                                              s.get('align_events', {}),
                                              g.node_params(PLANT), self.rate)
            if a.trace and t.size:
                np.savetxt(a.trace, np.column_stack([t, ref, y]), delimiter=',',
                           header='t_s,r_m,y_m', comments='')
        goal = self.h.cycle_goal if self.h is not None else 0.0
        s['goals_missed'] = sm.goals_missed(s, self.sync, goal)
        s['machine_limits'] = [m for m in [sm.machine_limit(s, self.sync, goal)] if m]
        print(sm.format_summary(s), flush=True)
        if a.summary:
            with open(a.summary, 'w', encoding='utf-8') as f:
                json.dump(s, f, indent=1, default=json_default)
