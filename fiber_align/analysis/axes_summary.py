# SPDX-License-Identifier: Apache-2.0
"""
The summary of a multi-axis run (``bringup --rig``, ``--station``), pure.

Per-axis realtime figures from the nodes' ``/diagnostics`` and the report for people
(ms, um).
"""

from fiber_align.analysis import run_summary as sm


def axis_figures(by_status, namespace, axes=('x', 'y')):
    """
    Return the realtime figures of each rig axis from its nodes' ``/diagnostics``.

    :param by_status: ``{'latest': {status name: values}, 'worst': {...}}`` (bringup's
        ``DiagnosticsWatch.by_status``: full status names).
    :returns: ``{axis: {missed_share, watchdog_count, ..., worst: {node: window}}}``
        (:func:`fiber_align.analysis.run_summary.realtime_figures`, SI).
    """
    out = {}
    for axis in axes:
        prefix = '/%s/%s/' % (namespace.strip('/'), axis) if namespace else '/%s/' % axis
        latest = {k[len(prefix):]: v for k, v in by_status['latest'].items()
                  if k.startswith(prefix)}
        out[axis] = dict(sm.realtime_figures(latest), worst={
            k[len(prefix):]: dict(v) for k, v in by_status['worst'].items()
            if k.startswith(prefix)})
    return out


def axis_goals(axes, floor, missed_goal):
    """
    Return ``(goals missed, machine limits)`` of a realtime multi-axis run, axis by axis.

    Each axis is held to the 1-D run's goals (:func:`~.run_summary.goals_missed`,
    :func:`~.run_summary.machine_limit`) against the one machine floor of the run.

    :param axes: :func:`axis_figures`; :param floor: the machine-floor probe's figures or
        ``None``; :param missed_goal: the share of missed periods allowed (1).
    :returns: two lists of texts, each led by its axis (``x: ...``).
    """
    per_axis = [(axis, {'realtime': rt, 'floor': floor}) for axis, rt in axes.items()]
    return (['%s: %s' % (axis, m) for axis, s in per_axis
             for m in sm.goals_missed(s, 'realtime', missed_goal)],
            ['%s: %s' % (axis, m) for axis, s in per_axis
             for m in [sm.machine_limit(s, 'realtime', missed_goal)] if m])


def print_report(summary):
    """Print the run for people (ms, um)."""
    off = summary.get('offline') or {}

    def worst(prefix):
        return max(v for k, v in off.items() if k.startswith(prefix))
    # the machine's name leads each line (the scenario names it: align2d the rig)
    name = {'align2d': 'rig'}.get(summary['scenario'], summary['scenario'])
    print('%s %s (%s, seed %d): %s, align at sample %s, time to peak %s ms, peak '
          'samples %s%s' % (name, summary['scenario'], summary['sync_mode'], summary['seed'],
                            summary.get('state') or summary['error'],
                            summary.get('align_sample'),
                            '%.1f' % (summary['time_to_peak_s'] * 1e3)
                            if summary.get('time_to_peak_s') is not None else '-',
                            summary.get('peak_samples'),
                            '' if not off else '; offline: %d samples compared, max |dx| '
                            '%.3g m, max |dsetpoint| %.3g m, max rel dP %.3g, %s'
                            % (off['samples'], worst('max_abs_m'), worst('max_abs_r'),
                               off['max_rel_p'],
                               'EQUAL' if off['equal'] else 'DIFFERENT')), flush=True)
    procs = {n: p.get('cpu_per_s') for n, p in summary.get('processes', {}).items()
             if p.get('cpu_per_s') is not None}
    if summary.get('cycles_tracking') is not None:
        print('%s: %d release / align cycles, each to TRACKING; time to peak %.1f-%.1f ms'
              % (name, summary['cycles_tracking'], 1e3 * min(summary['cycle_time_to_peak_s']),
                 1e3 * max(summary['cycle_time_to_peak_s'])), flush=True)
    if summary.get('axes'):
        print('%s realtime: %s' % (name, '; '.join(
            '%s missed %s %% of the cycles, %s watchdog trips' % (
                axis, '-' if rt.get('missed_share') is None else '%.3f' % (
                    100 * rt['missed_share']), rt.get('watchdog_count', '-'))
            for axis, rt in summary['axes'].items())), flush=True)
    if procs:
        print('%s CPU: %.2f core in all (%s)' % (name, sum(procs.values()), ', '.join(
            '%s %.2f' % kv for kv in sorted(procs.items()))), flush=True)
    if summary.get('floor'):
        print('%s: machine floor (bare loop beside the graph): %s'
              % (name, sm.floor_text(summary['floor'])), flush=True)
    for m in summary.get('goals_missed') or ():
        print('%s: GOAL MISSED: %s' % (name, m), flush=True)
    for m in summary.get('machine_limits') or ():
        print('%s: MACHINE: %s' % (name, m), flush=True)
