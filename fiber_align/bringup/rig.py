# SPDX-License-Identifier: Apache-2.0
"""
``bringup --rig``, ``--station``, ``--array``: start a multi-axis graph, align, stop.

``align`` after ``ALIGN_IDLE_S``, TRACKING within ``ALIGN_MAX_S`` (station, array: their
search timeout), ``LOSS_WINDOW_S`` more; lockstep: exit 1 when a stream differs from the
offline run's (:func:`fiber_align.analysis.run_summary.compare_offline`).
"""

import time

from fiber_align.analysis import run_summary as sm
from fiber_align.analysis.axes_summary import axis_figures, axis_goals, print_report
from fiber_align.bringup.harness import Harness, session
from fiber_align.bringup.observer import BringupError

#: The scenarios whose wait for TRACKING is bounded by the sequencer's own search timeout
#: (+ 2 s, as offline; the station's search may walk its whole square), not ``ALIGN_MAX_S``.
OWN_TIMEOUT = ('station', 'array')


def run_rig(a, g):
    """Run ``bringup --rig``, ``--station``, ``--array`` (options ``a``, graph ``g``): the code."""
    from rcl_interfaces.srv import SetParameters
    from std_srvs.srv import Trigger
    seq = g.node_params(g.own_nodes[-1])
    rate = float(seq['rate_hz'])
    streams = dict(g.streams)       # trace column -> topic (graph.rig.Machine.streams)
    max_s = float(seq['search_timeout_s']) + 2.0 if g.scenario in OWN_TIMEOUT \
        else sm.ALIGN_MAX_S
    summary = {'scenario': g.scenario, 'rig': True, 'sync_mode': g.sync_mode, 'seed': g.seed,
               'composed': g.composed, 'namespace': g.namespace, 'rate_hz': rate,
               'error': ''}
    # realtime without --trace: no stream; the waits count samples by the wall clock (an
    # observer that takes every stream at 1 kHz falls behind on a loaded machine, and its
    # reads are load the graph's users do not have)
    full = g.sync_mode == 'lockstep' or bool(a.trace)
    h = Harness(g, dict(streams=streams if full else {}), a.quiet)

    def ready():
        # clients made, servers found before the clock (a new client's answer can be lost)
        names = [(Trigger, 'align'), (Trigger, 'release')] + (
            [(SetParameters, g.own_nodes[-1] + '/set_parameters')] if a.part else [])
        return all([h.obs.client(*n).wait_for_service(timeout_sec=0.05) for n in names])

    def steps():
        h.start(ready=ready)
        obs, alive = h.obs, h.alive
        h.run(True)
        summary['startup_s'] = h.summary['startup_s']
        t_run = time.monotonic()
        clock = (lambda: obs.samples) if full else (
            lambda: int((time.monotonic() - t_run) * rate))

        def until(k):
            obs.wait(lambda: clock() >= k, 60.0, alive, 'sample %d' % k)

        parts = iter(range(1, 10 ** 6))

        def align(k_rest):
            """Rest ``ALIGN_IDLE_S`` from sample ``k_rest``, set the part (``--part``), align."""
            until(k_rest + int(round(sm.ALIGN_IDLE_S * rate)))
            if a.part:
                obs.set_text(g.own_nodes[-1], 'part_id', '%s-%d' % (a.part, next(parts)),
                             alive)
            k_align, _, tracking = obs.align(alive, clock, max_s * rate)
            if tracking is None:
                raise obs.ended('alignment')
            return k_align, tracking

        def release_align():
            """One switch cycle: ``release`` to IDLE, then align; return the time to peak."""
            obs.command('release', alive=alive)
            obs.wait(lambda: obs.status.get('state') in ('IDLE', 'FAULT'), 60.0, alive, 'IDLE')
            if obs.status.get('state') != 'IDLE':
                raise BringupError('release ended in FAULT: %s'
                                   % obs.status.get('fault_reason'))
            k_align, tracking = align(clock())
            return (tracking['sample'] - 1 - k_align) / rate

        k_align, tracking = align(0)
        # from the TRACKING sample: the status can arrive before the streams' samples
        until(max(clock(), tracking['sample']) + int(round(sm.LOSS_WINDOW_S * rate)) + 5)
        summary.update(align_sample=k_align, tracking_sample=tracking['sample'],
                       time_to_peak_s=(tracking['sample'] - 1 - k_align) / rate,
                       peak_samples=tracking['peak_samples'])
        cycles = [release_align() for _ in range(a.cycles or 0)]
        if cycles:
            summary.update(cycles_tracking=len(cycles), cycle_time_to_peak_s=cycles)
        if a.duration:
            # held aligned: TRACKING, or PEAKING again when the power drifts down
            k_end = clock() + int(round(a.duration * rate))
            obs.wait(lambda: clock() >= k_end or obs.status.get('state') in ('FAULT', 'IDLE'),
                     60.0 + 4.0 * a.duration, alive, 'sample %d' % k_end)
            if obs.status.get('state') in ('FAULT', 'IDLE'):
                raise BringupError('left alignment while held: %s %s' % (
                    obs.status.get('state'), obs.status.get('fault_reason') or ''))
        summary['run_wall_s'] = time.monotonic() - t_run
        obs.watch.run_to = time.monotonic()
        if g.sync_mode == 'realtime':
            # before the hold: a held plant stops the drivers' input (a watchdog trip)
            summary['axes'] = axis_figures(obs.watch.by_status, g.namespace, g.axes)
            floor = h.floor_figures()
            summary.update({'floor': floor} if floor is not None else {})
            summary['goals_missed'], summary['machine_limits'] = axis_goals(
                summary['axes'], floor, h.cycle_goal)
        h.run(False)
        summary.update(state=obs.status.get('state'), samples=clock())
        if g.sync_mode == 'lockstep' and not (a.cycles or a.duration):
            summary['offline'] = sm.compare_offline(g.scenario, g.seed, k_align,
                                                    obs.columns(streams))
            # the offline run has the shipped parameters: with others it is only reported
            comparable = not (a.param or a.params_file)
            summary['offline']['comparable'] = comparable
            return 0 if summary['offline']['equal'] or not comparable else 1
        return 0

    def stop(code):
        s = h.stop(code == 130)
        summary['children'] = {n: c['exit_code'] for n, c in s.get('children', {}).items()}
        summary['processes'] = s.get('processes', {})
        summary.update({k: s[k] for k in ('recorded', 'recorder_short', 'recorder_catch_up_s',
                                          'recording_stopped_early') if k in s})
        if a.trace and h.obs is not None:
            sm.write_trace(a.trace, h.obs.columns(streams), rate)   # full: every stream
        h.close()
        print_report(summary)
    return session(a, summary, steps, stop)
