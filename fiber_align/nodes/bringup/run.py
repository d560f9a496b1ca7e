# SPDX-License-Identifier: Apache-2.0
"""One bring-up: start the processes, run the scenario, stop in order, summarise."""

import json
import os
from pathlib import Path
import signal
import sys
import tempfile
import time

import numpy as np
import yaml

from fiber_align.analysis.report import hysteresis_metrics
from fiber_align.nodes.bringup import interrupt, summary as sm
from fiber_align.nodes.bringup.align import run_align
from fiber_align.nodes.bringup.checks import (dds_environment, expected_endpoints, usage,
                                              wait_recorder)
from fiber_align.nodes.bringup.children import Child, cpu_time_s
from fiber_align.nodes.bringup.diagnostics import DiagnosticsWatch, spin_thread
from fiber_align.nodes.bringup.cli import param_overrides, TRACKING_SCENARIOS
from fiber_align.nodes.bringup.observer import BadInput, BringupError, Runner, StartStall
from fiber_align.nodes.bringup.params import compose, namespaced, node_params
from fiber_align.nodes.graph import control_nodes, plant_reach_m
from fiber_align.nodes.scenario_runner import setpoint_range, Source

EXIT_OK, EXIT_FAIL, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
#: realtime goals ``--strict`` holds a run to: share of missed cycles, watchdog trips
MISSED_SHARE_GOAL = 0.001


def graph_nodes(scenario):
    """Return the node names the scenario runs (recorder excluded): the graph's own."""
    return control_nodes(scenario)


def _already_stopping(signum, frame):
    # os.write, not print: a handler that interrupted a print would re-enter its buffer
    os.write(1, b'bringup: already stopping (the stop is bounded by stop_timeout_s)\n')


class Bringup:
    """One bring-up: processes, orchestration, stop and summary."""

    def __init__(self, args):
        """
        Compose the parameters and decide what runs.

        :raises ConfigError: a bad params file or override (exit 2).
        """
        self.args = args
        graph0 = compose(args.params_file)
        gp = node_params(graph0, 'bringup')
        self.scenario = args.scenario or gp.get('scenario', 'none')
        self.sync = args.sync or node_params(graph0, 'simulated_actuator')['sync_mode']
        # default layout: composed in realtime (measured: the loop keeps its period), one
        # process per node in lockstep, where a composed graph runs samples far faster
        # than this process's Python executor observes them, and the sample-time steps of
        # a scenario (align: the switch cycles) would be timed on a lagging count
        self.composed = args.composed if args.composed is not None else \
            self.sync == 'realtime'
        ov = param_overrides(args, self.sync)
        if args.record:     # through the params file: a -p would lose to its section
            ov['bag_recorder'] = dict(ov.get('bag_recorder', {}),
                                      output=os.path.abspath(args.record),
                                      **({'storage': args.storage} if args.storage else {}))
        self.rate = float(args.rate or node_params(graph0, 'simulated_actuator')['rate_hz'])
        ov['/**']['rate_hz'] = self.rate
        self.params = compose(args.params_file, ov)
        self.gp = node_params(self.params, 'bringup')
        self.duration = args.duration if args.duration is not None else float(
            gp.get('duration_s', 0.0))
        self.cycles = args.cycles if args.cycles is not None else int(
            self.gp.get('switch_cycles', 5))
        self.names = graph_nodes(self.scenario)
        self.source = None
        if 'scenario_runner' in self.names:
            self.source = self._source(ov)
            self.params = compose(args.params_file, ov)
        if self.scenario == 'align':
            ov.setdefault('simulated_actuator', {})['optical_power_every'] = 1
            self.params = compose(args.params_file, ov)
        self.children, self.runner = [], None
        self.tmp = tempfile.TemporaryDirectory(prefix='fiber_align_bringup_')
        self.params_file = str(Path(self.tmp.name) / 'fiber_align_params.yaml')
        with open(self.params_file, 'w', encoding='utf-8') as f:
            yaml.safe_dump(namespaced(self.params, args.namespace), f, sort_keys=False)
        self.stopping = False
        self.interrupted = False
        self.endpoints = {}
        self._next_check = 0.0
        self.summary = {}
        self.watch = None               # DiagnosticsWatch, once the graph starts
        self.cpu0 = {}

    def _source(self, ov):
        """Return the scenario's Source and set the runner's overrides (reach, duration)."""
        reach = plant_reach_m(self.params)
        name = self.scenario
        sp = node_params(self.params, 'scenario_runner')
        src = Source(name, *setpoint_range(sp['setpoint_min_m'], sp['setpoint_max_m'],
                                           reach))
        if self.duration <= 0:
            self.duration = float(src.sc.duration_s)
        ov['scenario_runner'] = {'scenario': name, 'duration_s': float(self.duration),
                                 'reach_m': float(reach)}
        return src

    # -- processes ------------------------------------------------------------------
    def _spawn(self, module, name, extra=(), pre=()):
        ros = ['--ros-args', '--params-file', self.params_file]
        if self.args.namespace:
            ros += ['-r', '__ns:=/' + self.args.namespace]
        cmd = [sys.executable, '-m', module] + list(pre) + ros + list(extra)
        ch = Child(name, cmd, dds_environment(), self.args.quiet)
        self.children.append(ch)
        self.cpu0[name] = (time.monotonic(), 0.0)
        print('bringup: started %s (pid %d)' % (name, ch.proc.pid), flush=True)

    def _alive(self):
        interrupt.check()
        for ch in self.children:
            if not ch.alive() and ch.proc.returncode == 2:
                ch.thread.join(timeout=1.0)
                raise BadInput(ch.last_error or '%s refused its parameters' % ch.name)
            if not ch.alive():
                why = (': ' + ch.last_error) if ch.last_error else ''
                raise BringupError('%s exited with code %s%s'
                                   % (ch.name, ch.proc.returncode, why))
        now = time.monotonic()
        if self.endpoints and self.runner is not None and now >= self._next_check:
            self._next_check = now + 1.0
            extra = self.runner.foreign_publishers(self.endpoints)
            if extra:
                raise BringupError(
                    'another graph shares ROS_DOMAIN_ID=%s: %s; run on a domain of its own'
                    % (os.environ.get('ROS_DOMAIN_ID', '0'), ', '.join(extra)))

    def _check_alone(self):
        """Refuse to start beside another graph in the same namespace and domain."""
        time.sleep(float(self.gp.get('discovery_wait_s', 0.5)))
        others = [n for n in self.names if self.runner.count_nodes(n)]
        if others:
            raise BringupError(
                'another fiber_align graph runs on ROS_DOMAIN_ID=%s in namespace /%s (its '
                'nodes: %s); stop it, or use --namespace or another ROS_DOMAIN_ID'
                % (os.environ.get('ROS_DOMAIN_ID', '0'), self.args.namespace,
                   ', '.join(others)))

    # -- run ------------------------------------------------------------------------
    def run(self):
        """Run the whole bring-up; return the exit code."""
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        code = EXIT_OK
        retries = int(self.gp.get('start_retries', 2))
        try:
            for attempt in range(retries + 1):
                try:
                    self._start()
                    self._run_scenario()
                    break
                except StartStall as exc:
                    if attempt == retries:
                        raise
                    print('bringup: %s; restarting the graph (restart %d, counted in the '
                          'summary)' % (exc, attempt + 1), flush=True)
                    self._stop()
                    self._reset()
                    self.summary['restarts'] = attempt + 1
        except KeyboardInterrupt:
            interrupt.handled()
            print('bringup: interrupted, stopping', flush=True)
            code = EXIT_INTERRUPTED
            self.interrupted = True
            self.summary['interrupted'] = True
        except BadInput as exc:
            print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
            self.summary['error'] = str(exc)
            code = EXIT_BAD_INPUT
        except BringupError as exc:
            print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
            self.summary['error'] = str(exc)
            code = EXIT_FAIL
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, _already_stopping)
            self._stop()
            self._report()
            rclpy.try_shutdown()
            self.tmp.cleanup()
        if code == EXIT_OK and self.args.strict and self.summary.get('goals_missed'):
            print('bringup: --strict: %s' % '; '.join(self.summary['goals_missed']),
                  file=sys.stderr, flush=True)
            code = EXIT_FAIL
        return code

    def _reset(self):
        """Forget a stopped attempt: processes, runner, its bag and its summary."""
        import shutil
        self.children, self.runner = [], None
        self.endpoints, self._next_check = {}, 0.0
        self.stopping = False
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, interrupt.handler)
        for k in ('sent', 'recorded', 'children', 'stop_s', 'recorder_catch_up_s',
                  'startup_s', 'run_wall_s'):
            self.summary.pop(k, None)
        if self.args.record and os.path.isdir(self.args.record):
            shutil.rmtree(self.args.record)

    def _start(self):
        from rclpy.executors import SingleThreadedExecutor
        t_start = time.monotonic()
        timeout = float(self.gp.get('startup_timeout_s', 30.0))
        lockstep = self.sync == 'lockstep'
        self.runner = Runner(self.args.namespace, self.source, lockstep, self.rate,
                             self.duration if self.source is not None else float('inf'))
        self.runner.stall_s = float(self.gp.get('stall_timeout_s', 10.0))
        self.runner.start_stall_s = float(self.gp.get('start_stall_timeout_s', 3.0))
        # not the EventsExecutor: a service call from the main thread while it spins
        # the observer can deadlock in rclpy Jazzy (seen: bringup hung at 40 % CPU)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.runner.node)
        self.watch = DiagnosticsWatch(self.args.namespace)
        self.spin_thread = spin_thread(self.executor)
        if not self.summary.get('restarts'):
            self._check_alone()
        if self.args.record:
            self._spawn('fiber_align.nodes.bag_recorder', 'bag_recorder')
        if self.composed:
            self._spawn('fiber_align.nodes.control_graph', 'control_graph',
                        pre=['--nodes', ','.join(self.names)])
        else:
            for n in self.names:
                self._spawn('fiber_align.nodes.' + n, n)
        all_names = list(self.names) + (['bag_recorder'] if self.args.record else [])
        self.runner.wait_nodes(all_names, timeout, self._alive)
        self.runner.activate_driver(timeout, self._alive)
        recorded = node_params(self.params, 'bag_recorder')['topics'] \
            if self.args.record else ()
        want = expected_endpoints(self.scenario, lockstep, recorded, self.composed)
        self.runner.wait_matched(want, timeout, self._alive)
        self.endpoints = want
        self._alive()
        self.summary['startup_s'] = time.monotonic() - t_start
        for ch in self.children:
            self.cpu0[ch.name] = (time.monotonic(), cpu_time_s(ch.proc.pid))
        print('bringup: graph up in %.2f s (%s, %g Hz, %s, %s)'
              % (self.summary['startup_s'], self.sync, self.rate, self.args.controller,
                 'composed' if self.composed else 'multi-process'), flush=True)

    def _run_scenario(self):
        r = self.runner
        t0 = time.monotonic()
        if self.scenario == 'none':
            r.set_running(True)
            self.watch.run_from = time.monotonic()
            print('bringup: running; publish `setpoint` (m). Ctrl-C stops.', flush=True)
            while True:
                self._alive()
                time.sleep(0.1)
        r.start()
        r.set_running(True)
        self.watch.run_from = time.monotonic()
        try:
            if self.scenario == 'align':
                self.summary['align_events'] = run_align(self)
                return
            wall_limit = 60.0 + 20.0 * self.duration
            while True:
                self._alive()
                r.check_stall()
                if r.done.wait(0.02):
                    break
                if time.monotonic() - t0 > wall_limit:
                    raise BringupError('scenario did not finish within %g s' % wall_limit)
        finally:
            self.summary['run_wall_s'] = time.monotonic() - t0
            self.watch.run_to = time.monotonic()

    # -- stop -----------------------------------------------------------------------
    @property
    def diag(self):
        """Return node -> its newest /diagnostics values (empty before the graph starts)."""
        return self.watch.latest if self.watch is not None else {}

    def _stop(self):
        """Hold the plant, SIGINT the nodes, then the recorder, all within stop_timeout_s."""
        if self.stopping:
            return
        self.stopping = True
        t_stop = time.monotonic()
        stop_s = float(self.gp.get('stop_timeout_s', 5.0))
        deadline = t_stop + max(1.0, stop_s - 0.5)
        r = self.runner
        self._usage()
        # the realtime figures of the run itself: holding the plant below stops the
        # loop's input, which the driver's watchdog then reports as a trip
        self.summary['realtime'] = sm.realtime_figures(self.diag)
        self.summary['cycles'] = self.watch.worst_windows() if self.watch else {}
        if r is not None:
            r.active = False
            try:
                if r.run_cli.service_is_ready() and all(
                        ch.alive() for ch in self.children if ch.name != 'bag_recorder'):
                    r.set_running(False, timeout=0.5)
            except BringupError:
                pass
            time.sleep(0.1)   # in-flight messages reach their subscribers
        nodes = [ch for ch in self.children if ch.name != 'bag_recorder']
        rec = [ch for ch in self.children if ch.name == 'bag_recorder']
        if rec and rec[0].alive():
            # the graph is held: let the recorder work through its backlog before the
            # publishers go (a writer that exits takes its undelivered samples with it)
            limit = (deadline - 2.5 - time.monotonic()) if self.interrupted else 30.0
            self.summary['recorder_catch_up_s'] = self._wait_recorder(rec[0], max(0.5, limit))
        for ch in nodes:
            ch.interrupt()
        node_deadline = deadline - (1.5 if rec else 0.0)
        for ch in nodes:
            ch.wait(node_deadline - time.monotonic())
        for ch in rec:
            ch.interrupt()
            # at least 4 s: the recorder drains up to 3 s while the graph still publishes,
            # then closes the bag; a SIGKILL before that leaves it without metadata
            ch.wait(max(deadline - time.monotonic(), 4.0))
        if r is not None:
            self.executor.shutdown(timeout_sec=0.5)
            # the spin threads must have left rclpy before the process ends (a thread
            # still inside it at exit aborts the process: "terminate called ...")
            if self.watch is not None:
                self.watch.close()
            if getattr(self, 'spin_thread', None) is not None:
                self.spin_thread.join(timeout=2.0)
            r.destroy()
        for ch in self.children:
            self.summary.setdefault('sent', {}).update(ch.sent)
        self.summary['children'] = {ch.name: {'pid': ch.proc.pid,
                                              'exit_code': ch.proc.returncode}
                                    for ch in self.children}
        self.summary['stop_s'] = time.monotonic() - t_stop
        if self.args.record:
            counts = Path(self.args.record) / 'recorder_counts.json'
            if counts.is_file():
                self.summary['recorded'] = json.loads(counts.read_text(encoding='utf-8'))

    def _wait_recorder(self, ch, limit_s):
        """Wait until the recorder holds what the nodes sent; return the wait (s)."""
        waited, short = wait_recorder(self.diag, self.names, ch, limit_s)
        if short:
            self.summary['recorder_short'] = {k: list(v) for k, v in short.items()}
        return waited

    def _usage(self):
        """Note CPU (s per s of run) and resident memory (MB) of every process."""
        out = usage(self.children, self.cpu0)
        if out:
            self.summary['processes'] = out

    # -- summary --------------------------------------------------------------------
    def _report(self):
        s = self.summary
        s.update({'scenario': self.scenario, 'sync_mode': self.sync, 'rate_hz': self.rate,
                  'controller': self.args.controller, 'composed': self.composed,
                  'namespace': self.args.namespace,
                  'model_file': os.path.abspath(self.args.model) if self.args.model else None,
                  'record': os.path.abspath(self.args.record) if self.args.record else None})
        s.setdefault('realtime', sm.realtime_figures(self.diag))
        r = self.runner
        if r is not None:
            t, ref, y = r.trace()
            s['samples'] = int(t.size)
            if t.size > 2 and self.scenario in TRACKING_SCENARIOS:
                s['metrics'] = sm.scenario_metrics(self.scenario, t, ref, y, r.series('v'))
            elif t.size > 2 and self.scenario == 'hysteresis-experiment':
                s['metrics'] = hysteresis_metrics(r.series('v'), y)
            elif t.size > 2 and self.scenario == 'align':
                s['align'] = sm.align_metrics(t, y, r.series('p'), r.states,
                                              s.get('align_events', {}), self.params,
                                              self.rate)
            if self.args.trace and t.size:
                np.savetxt(self.args.trace, np.column_stack([t, ref, y]), delimiter=',',
                           header='t_s,r_m,y_m', comments='')
        s['goals_missed'] = sm.goals_missed(s, self.sync, MISSED_SHARE_GOAL)
        print(sm.format_summary(s), flush=True)
        if self.args.summary:
            with open(self.args.summary, 'w', encoding='utf-8') as f:
                json.dump(s, f, indent=1, default=sm.json_default)
