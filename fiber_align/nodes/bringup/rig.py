# SPDX-License-Identifier: Apache-2.0
"""
``bringup --rig``: start the two-axis rig (``graph_rig.py``), run ``align2d``, stop.

Sequence: write the rig's params file (plants held: ``autostart`` false), start its
processes (:mod:`~fiber_align.nodes.bringup.children`), wait until ``lifecycle_manager``
has both drivers active, start both plants (``x/simulated_actuator/run``,
``y/simulated_actuator/run``), let ``ALIGN_IDLE_S`` of samples pass, call ``align``, wait
for TRACKING (at most ``ALIGN_MAX_S`` of sample time), ``LOSS_WINDOW_S`` more, hold both
plants, stop every process. The observer records, per sample, both displacements, the
optical power and both setpoints (reliable, deep, transient local: every sample).

In lockstep the run is compared with the offline run of the same description
(:func:`fiber_align.analysis.run_summary.compare_offline`: the offline ``align2d`` with
the ``align`` command before the same sample): the summary's ``offline`` holds the largest
difference of each stream, and the exit code is 1 when one exceeds the tolerance.
"""

import json
import time

from fiber_align.analysis import run_summary as sm
from fiber_align.graph import rig as gr
from fiber_align.nodes.bringup import interrupt
from fiber_align.nodes.bringup.observer import BringupError
from fiber_align.nodes.bringup.run import Harness

#: Streams recorded per sample: name -> topic.
STREAMS = {'mx': 'x/displacement', 'my': 'y/displacement', 'p': 'optical_power',
           'rx': 'x/setpoint', 'ry': 'y/setpoint'}


def arrays(obs):
    """Return every stream of the observer, cut to the complete samples (SI arrays)."""
    return {k: obs.series(k) for k in STREAMS}


def run_rig(a, g):
    """Run ``bringup --rig`` (options ``a``, graph ``g``); return the exit code."""
    from std_srvs.srv import Trigger
    rate = float(g.node_params(gr.SEQUENCER_2D)['rate_hz'])
    summary = {'scenario': 'align2d', 'rig': True, 'sync_mode': g.sync_mode, 'seed': g.seed,
               'composed': g.composed, 'namespace': g.namespace, 'rate_hz': rate,
               'error': ''}
    h = Harness(g, dict(streams=STREAMS), a.quiet)
    code = 0
    try:
        # the align server discovered before the clock starts: a late discovery would
        # otherwise let the lockstep graph idle on for seconds before the command
        h.start(check_alone=False, ready=lambda: h.obs.client(Trigger, 'align')
                .wait_for_service(timeout_sec=0.1))
        obs, alive = h.obs, h.alive
        align = obs.client(Trigger, 'align')
        h.run(True)
        summary['startup_s'] = h.summary['startup_s']
        t_run = time.monotonic()
        k = int(round(sm.ALIGN_IDLE_S * rate))
        obs.wait(lambda: obs.samples >= k, 60.0, alive, 'sample %d' % k)
        res = obs.call(align, Trigger.Request(), 10.0, alive)
        if not res.success:
            raise BringupError('align refused: %s' % res.message)
        obs.wait(lambda: obs.status.get('align_sample') is not None, 10.0, alive,
                 'the align answer')
        k_align = obs.status['align_sample']
        obs.wait(lambda: obs.status.get('state') in ('TRACKING', 'FAULT')
                 or obs.samples > k_align + sm.ALIGN_MAX_S * rate, 120.0, alive, 'TRACKING')
        _, tracking = obs.first('TRACKING')
        if tracking is None:
            raise BringupError('alignment ended in %s: %s' % (
                obs.status.get('state'), obs.status.get('fault_reason') or 'timeout'))
        k_end = tracking['sample'] + int(round(sm.LOSS_WINDOW_S * rate)) + 5
        obs.wait(lambda: obs.samples >= k_end, 60.0, alive, 'sample %d' % k_end)
        h.run(False)
        summary['run_wall_s'] = time.monotonic() - t_run
        summary.update(align_sample=k_align, tracking_sample=tracking['sample'],
                       time_to_peak_s=(tracking['sample'] - 1 - k_align) / rate,
                       peak_samples=tracking['peak_samples'], state=obs.status.get('state'),
                       samples=obs.samples)
        if g.sync_mode == 'lockstep':
            summary['offline'] = sm.compare_offline(g.seed, k_align, arrays(obs))
            # the offline run has the shipped parameters: with others it is only reported
            comparable = not (a.param or a.params_file)
            summary['offline']['comparable'] = comparable
            code = 0 if summary['offline']['equal'] or not comparable else 1
    except BringupError as exc:
        summary['error'] = str(exc)
        code = 1
    except KeyboardInterrupt:
        interrupt.handled()
        summary['error'] = 'interrupted'
        code = 130
    finally:
        s = h.stop(code == 130)
        summary['children'] = {n: c['exit_code'] for n, c in s.get('children', {}).items()}
        if a.trace and h.obs is not None:
            sm.write_trace(a.trace, arrays(h.obs), rate)
        h.close()
    _report(summary, a)
    return code


def _report(summary, a):
    """Print the run for people (ms, um) and write ``--summary`` (JSON, SI)."""
    if a.summary:
        with open(a.summary, 'w', encoding='utf-8') as f:
            json.dump(summary, f, indent=2, sort_keys=True, default=str)
    off = summary.get('offline') or {}
    print('rig align2d (%s, seed %d): %s, align at sample %s, time to peak %s ms, peak '
          'samples %s%s' % (summary['sync_mode'], summary['seed'],
                            summary.get('state') or summary['error'],
                            summary.get('align_sample'),
                            '%.1f' % (summary['time_to_peak_s'] * 1e3)
                            if summary.get('time_to_peak_s') is not None else '-',
                            summary.get('peak_samples'),
                            '' if not off else '; offline: %d samples compared, max |dx| '
                            '%.3g m, max |dsetpoint| %.3g m, max rel dP %.3g, %s'
                            % (off['samples'], max(off['max_abs_mx'], off['max_abs_my']),
                               max(off['max_abs_rx'], off['max_abs_ry']), off['max_rel_p'],
                               'EQUAL' if off['equal'] else 'DIFFERENT')), flush=True)
