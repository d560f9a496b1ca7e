# SPDX-License-Identifier: Apache-2.0
"""
``bringup`` on the simulated 1-D graph: its scenario on a :class:`~.harness.Harness`.

Start the plant, run the scenario (``scenario_runner``; ``align``: the sequencer, then
``--cycles`` switch cycles; ``none``: until SIGINT), print the summary. A stalled lockstep
start is retried; a recorded realtime scenario's figures come from its bag.
"""

import os
import shutil
import time

import numpy as np

from fiber_align.analysis import run_summary as sm
from fiber_align.analysis.run_record import record_from_bag
from fiber_align.bringup.harness import EXIT_INTERRUPTED, EXIT_OK, Harness, session, settings
from fiber_align.bringup.observer import BringupError, StartStall
from fiber_align.graph.params import PLANT, SCENARIO_RUNNER
from fiber_align.graph.registry import expected_endpoints


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
        #: a recorded realtime scenario: the figures from the bag, the progress from the
        #: plant's /diagnostics ``sample``, the end from ``scenario_state``
        self.from_bag = bool(graph.record) and self.sync == 'realtime' and source is not None
        self._plant_sample = None

    def _harness(self):
        streams = {} if self.from_bag else {'y': 'displacement', 'v': 'drive_voltage'}
        if self.source is None:
            streams.update(r_ref='reference', p='optical_power')
        want = expected_endpoints(self.graph, tuple(streams.values()) + (
            ('alignment_state',) if self.source is None else ()))
        return Harness(self.graph, dict(streams=streams, clock='y' if streams else None,
                                        source=self.source, lockstep=self.sync == 'lockstep',
                                        rate_hz=self.rate, duration_s=self.duration),
                       self.args.quiet, want)

    def run(self):
        """Run the whole bring-up; return the exit code."""
        return session(self.args, self.summary, self._steps, self._stop)

    def _steps(self):
        retries = int(settings(self.graph)['start_retries'])
        for attempt in range(retries + 1):
            self.h = self._harness()
            try:
                self.h.start()
                print('bringup: graph up in %.2f s (%s, %g Hz, %s, %s)' % (
                    self.h.summary['startup_s'], self.sync, self.rate, self.graph.controller,
                    'composed' if self.graph.composed else 'multi-process'), flush=True)
                self._run_scenario()
                return EXIT_OK
            except StartStall as exc:
                if attempt == retries:
                    raise
                print('bringup: %s; restarting the graph (restart %d, counted in the '
                      'summary)' % (exc, attempt + 1), flush=True)
                self.h.stop()
                self.h.close()
                self.summary['restarts'] = attempt + 1
                if self.graph.record and os.path.isdir(self.graph.record):
                    shutil.rmtree(self.graph.record)

    def _stop(self, code):
        if self.h is not None:
            self.summary.update(self.h.stop(code == EXIT_INTERRUPTED))
            self._report()
            self.h.close()

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
                if self.from_bag and self._bag_run_over(r):
                    break
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

    def _bag_run_over(self, r):
        """Return True once the runner said ``done``; else note the plant's progress."""
        if r.runner_done_at is not None:
            return True
        k = r.watch.latest.get(PLANT, {}).get('sample')
        if k is not None and k != self._plant_sample:
            self._plant_sample, r.progress = k, time.monotonic()
        return False

    def _align(self):
        """
        Align, hold, run ``self.cycles`` switch cycles; return the events (sample indices).

        Waits count samples (sample time), each bounded in wall time.

        :raises BringupError: a refused call, a FAULT, a timeout.
        """
        r, alive = self.h.obs, self.h.alive

        def k(seconds):
            return int(round(seconds * self.rate))

        def ended(what):
            self.summary['align_events'] = events
            return r.ended(what)

        events = {}
        wall = 30.0 + 40.0 * (sm.ALIGN_MAX_S + self.cycles * (sm.SWITCH_OFF_S
                                                              + sm.SWITCH_ON_S))
        r.wait_samples(k(sm.ALIGN_IDLE_S), wall, alive)
        events['align'], k_tracking, _ = r.align(lambda: (alive(), r.check_stall()),
                                                 lambda: r.samples, k(sm.ALIGN_MAX_S), wall)
        if k_tracking is None:
            raise ended('alignment')
        events['tracking'] = k_tracking
        r.wait_samples(events['tracking'] + k(sm.LOSS_WINDOW_S), wall, alive)
        events['cycles'] = []
        for _ in range(self.cycles):
            k_off = r.command('switch', False, alive)
            r.wait_samples(k_off + k(sm.SWITCH_OFF_S), wall, alive)
            k_on = r.command('switch', True, alive)
            r.wait_samples(k_on + k(sm.SWITCH_ON_S), wall, alive)
            # the re-peak takes about 55 of the 60 samples: a status a few samples late (a
            # loaded machine) is waited for, within the alignment's own bound
            r.wait_samples(k_on + k(sm.ALIGN_MAX_S), wall, alive,
                           lambda: r.status.get('state') in ('TRACKING', 'FAULT'))
            events['cycles'].append((k_off, k_on, r.samples))
            if r.status.get('state') == 'FAULT':
                break
        if r.status.get('state') != 'TRACKING':
            raise ended('switch cycles')
        return events

    def _report(self):
        s, a, g = self.summary, self.args, self.graph
        s.update({'scenario': self.scenario, 'sync_mode': self.sync, 'rate_hz': self.rate,
                  'controller': g.controller, 'composed': g.composed,
                  'namespace': g.namespace, 'record': g.record or None,
                  'model_file': os.path.abspath(a.model) if a.model else None})
        r = self.h.obs
        if r is not None:
            if self.from_bag:
                r, error = record_from_bag(g.record, self.source, self.rate, self.duration)
                s.update({'error': error} if error else {})
            s['figures_from'] = 'bag' if self.from_bag else 'observer'
            t, ref, y = r.trace()
            if self.source is None:
                ref = r.series('r_ref')
            s['samples'] = int(t.size)
            s.update(sm.run_figures(self.scenario, t, ref, y, r.series, r.states,
                                    s.get('align_events', {}), g.node_params(PLANT),
                                    self.rate))
            if a.trace and t.size:
                np.savetxt(a.trace, np.column_stack([t, ref, y]), delimiter=',',
                           header='t_s,r_m,y_m', comments='')
        goal = self.h.cycle_goal if self.h is not None else 0.0
        s['goals_missed'] = sm.goals_missed(s, self.sync, goal)
        s['machine_limits'] = [m for m in [sm.machine_limit(s, self.sync, goal)] if m]
        print(sm.format_summary(s), flush=True)
