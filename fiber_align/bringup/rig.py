# SPDX-License-Identifier: Apache-2.0
"""
``bringup --rig``, ``--station``, ``--array``: start a multi-axis graph, align, stop.

The plants start held until every driver is active; then ``align`` after
``ALIGN_IDLE_S`` of samples, TRACKING within ``ALIGN_MAX_S`` (the station: its search
timeout), ``LOSS_WINDOW_S`` more. In lockstep the run is compared with the offline run
of the same description (:func:`fiber_align.analysis.run_summary.compare_offline`); the
exit code is 1 when a stream differs beyond the tolerance. docs/alignment2d.md, docs/station.md.
"""

import time

from fiber_align.analysis import run_summary as sm
from fiber_align.analysis.axes_summary import axis_figures, print_report
from fiber_align.bringup.harness import Harness, session
from fiber_align.bringup.observer import BringupError
from fiber_align.graph.registry import STATION_AXES as AXES4
from fiber_align.simulation import array_scenarios as asc
from fiber_align.simulation import station_scenarios as sc

#: Streams recorded per sample: name -> topic. The setpoints as the loop accepted them
#: (``reference``): a command topic keeps one reader, the loop's (graph.registry.COMMANDS).
STREAMS = {'mx': 'x/displacement', 'my': 'y/displacement', 'p': 'optical_power',
           'rx': 'x/reference', 'ry': 'y/reference'}
#: The station's (``bringup --station``): the offline bench's trace columns
#: (:class:`fiber_align.simulation.station_scenarios.StationBench`).
STATION_STREAMS = dict([('m' + k, a + '/displacement') for k, a in zip(sc.AXIS_KEYS, AXES4)]
                       + [('r' + k, a + '/reference') for k, a in zip(sc.AXIS_KEYS, AXES4)]
                       + [('p', 'optical_power')])
#: The array's (``bringup --array``): :class:`fiber_align.simulation.array_scenarios.
#: ArrayBench`'s trace columns, the outer channels' readings ``p_1`` and ``p_n``.
_AB = asc.ArrayBench
ARRAY_STREAMS = dict([(k, a + '/displacement') for k, a in zip(_AB.MEASURED, _AB.POSITION)]
                     + [(k, a + '/reference') for k, a in zip(_AB.SETPOINT, _AB.POSITION)]
                     + list(zip(_AB.POWERS, ('optical_power', 'optical_power_n'))))


#: What differs between the multi-axis graphs, by their scenario: the per-sample streams,
#: the offline run a lockstep run is compared with, and whether the wait for TRACKING is
#: bounded by the sequencer's own search timeout (+ 2 s, as offline; the station's search
#: may walk its whole square) or by ``ALIGN_MAX_S``.
KINDS = {'align2d': (STREAMS, sm.compare_offline, False),
         'station': (STATION_STREAMS, sm.compare_offline_station, True),
         'array': (ARRAY_STREAMS, sm.compare_offline_array, True)}


def arrays(obs, streams=STREAMS):
    """Return every stream of the observer, cut to the complete samples (SI arrays)."""
    return {k: obs.series(k) for k in streams}


def run_rig(a, g):
    """Run ``bringup --rig`` or ``--station`` (options ``a``, graph ``g``); return the code."""
    from std_srvs.srv import Trigger
    seq = g.node_params(g.own_nodes[-1])
    rate = float(seq['rate_hz'])
    streams, compare, own_timeout = KINDS[g.scenario]
    max_s = float(seq['search_timeout_s']) + 2.0 if own_timeout else sm.ALIGN_MAX_S
    summary = {'scenario': g.scenario, 'rig': True, 'sync_mode': g.sync_mode, 'seed': g.seed,
               'composed': g.composed, 'namespace': g.namespace, 'rate_hz': rate,
               'error': ''}
    # realtime without --trace: no stream; the waits count samples by the wall clock (an
    # observer that takes every stream at 1 kHz falls behind on a loaded machine, and its
    # reads are load the graph's users do not have)
    full = g.sync_mode == 'lockstep' or bool(a.trace)
    h = Harness(g, dict(streams=streams if full else {}), a.quiet)

    def steps():
        # the align server discovered before the clock starts: a late discovery would
        # otherwise let the lockstep graph idle on for seconds before the command
        h.start(ready=lambda: h.obs.client(Trigger, 'align')
                .wait_for_service(timeout_sec=0.1))
        obs, alive = h.obs, h.alive
        h.run(True)
        summary['startup_s'] = h.summary['startup_s']
        t_run = time.monotonic()
        clock = (lambda: obs.samples) if full else (
            lambda: int((time.monotonic() - t_run) * rate))
        k = int(round(sm.ALIGN_IDLE_S * rate))
        obs.wait(lambda: clock() >= k, 60.0, alive, 'sample %d' % k)
        parts = iter(range(1, 10 ** 6))
        part = (lambda: obs.set_text(g.own_nodes[-1], 'part_id', '%s-%d' % (
            a.part, next(parts)), alive)) if a.part else (lambda: None)
        part()
        k_align, tracking = _align(obs, alive, rate, clock, max_s)
        # from the TRACKING sample: the status can arrive before the streams' samples
        k_end = max(clock(), tracking['sample']) + int(round(sm.LOSS_WINDOW_S * rate)) + 5
        obs.wait(lambda: clock() >= k_end, 60.0, alive, 'sample %d' % k_end)
        summary.update(align_sample=k_align, tracking_sample=tracking['sample'],
                       time_to_peak_s=(tracking['sample'] - 1 - k_align) / rate,
                       peak_samples=tracking['peak_samples'])
        cycles = [_release_align(obs, alive, rate, clock, max_s, part)
                  for _ in range(a.cycles or 0)]
        if cycles:
            summary['cycles_tracking'] = len(cycles)
            summary['cycle_time_to_peak_s'] = cycles
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
            _realtime(summary, h, g)
        h.run(False)
        summary.update(state=obs.status.get('state'), samples=clock())
        if g.sync_mode == 'lockstep' and not (a.cycles or a.duration):
            summary['offline'] = compare(g.seed, k_align, arrays(obs, streams))
            # the offline run has the shipped parameters: with others it is only reported
            comparable = not (a.param or a.params_file)
            summary['offline']['comparable'] = comparable
            return 0 if summary['offline']['equal'] or not comparable else 1
        return 0

    def stop(code):
        s = h.stop(code == 130)
        summary['children'] = {n: c['exit_code'] for n, c in s.get('children', {}).items()}
        summary['processes'] = s.get('processes', {})
        for k in ('recorded', 'recorder_short', 'recorder_catch_up_s',
                  'recording_stopped_early'):
            if k in s:
                summary[k] = s[k]
        if a.trace and h.obs is not None:
            sm.write_trace(a.trace, arrays(h.obs, streams), rate)   # full: every stream
        h.close()
        print_report(summary)
    return session(a, summary, steps, stop)


def _realtime(summary, h, g):
    """Put each axis's realtime figures, the floor's, missed goals and limits in ``summary``."""
    summary['axes'] = axis_figures(h.obs.watch.by_status, g.namespace, g.axes)
    floor = h.floor_figures()
    if floor is not None:
        summary['floor'] = floor
    per_axis = [(axis, {'realtime': rt, 'floor': floor}) for axis, rt in summary['axes'].items()]
    summary['goals_missed'] = ['%s: %s' % (axis, m) for axis, s in per_axis
                               for m in sm.goals_missed(s, 'realtime', h.cycle_goal)]
    summary['machine_limits'] = ['%s: %s' % (axis, m) for axis, s in per_axis
                                 for m in [sm.machine_limit(s, 'realtime', h.cycle_goal)] if m]


def _align(obs, alive, rate, clock, max_s=sm.ALIGN_MAX_S):
    """
    Call ``align`` and wait for TRACKING; return ``(align sample, TRACKING status)``.

    :param clock: returns the samples so far (the wait's bound is in sample time).
    :param max_s: the bound (s of sample time).
    """
    k_align = obs.command('align', alive=alive)
    k_max = clock() + max_s * rate
    obs.wait(lambda: obs.status.get('state') in ('TRACKING', 'FAULT') or clock() > k_max,
             120.0, alive, 'TRACKING')
    _, tracking = obs.first('TRACKING', k_align)
    if tracking is None:
        raise BringupError('alignment ended in %s: %s' % (
            obs.status.get('state'), obs.status.get('fault_reason') or 'timeout'))
    return k_align, tracking


def _release_align(obs, alive, rate, clock, max_s=sm.ALIGN_MAX_S, part=lambda: None):
    """
    One switch cycle of the rig: ``release`` to IDLE, then ``align`` to TRACKING.

    :param part: sets the next part (``--part``) before the align.
    :returns: the time to peak of the new alignment (s of sample time).
    :raises BringupError: a refused call, a FAULT, a timeout.
    """
    obs.command('release', alive=alive)
    obs.wait(lambda: obs.status.get('state') in ('IDLE', 'FAULT'), 60.0, alive, 'IDLE')
    if obs.status.get('state') != 'IDLE':
        raise BringupError('release ended in FAULT: %s' % obs.status.get('fault_reason'))
    k = clock() + int(round(sm.ALIGN_IDLE_S * rate))
    obs.wait(lambda: clock() >= k, 60.0, alive, 'sample %d' % k)
    part()
    k_align, tracking = _align(obs, alive, rate, clock, max_s)
    return (tracking['sample'] - 1 - k_align) / rate
