# SPDX-License-Identifier: Apache-2.0
"""
The figures of a run on the ROS graph (``bringup``): metrics, realtime figures, summary.

Pure (no rclpy): the observer's per-sample arrays and the nodes' ``/diagnostics`` values
in, SI figures and the printed Markdown summary out. The metrics are computed by the
functions ``fiber-align simulate`` and ``analyze`` use, so a run on the graph and an
offline run are scored alike.
"""

import math

import numpy as np

from fiber_align.analysis.report import default_params, hysteresis_metrics
from fiber_align.plant.optics import OpticalLink
from fiber_align.simulation import alignment2d_scenarios as a2, scenarios
from fiber_align.simulation import array_scenarios as asc
from fiber_align.simulation import harness as hs
from fiber_align.simulation import station_scenarios as sc
from fiber_align.simulation.alignment_scenarios import rise_time
from fiber_align.simulation.metrics import loop_metrics, run_scores, step_settings, STEP_KEYS
from fiber_align.simulation.simulate import tracking_skip_s

#: align scenario timing (s of sample time): rest before ``align``, loss window after
#: TRACKING, switch off and on times, level window at the end of each on time
ALIGN_IDLE_S = 0.02
ALIGN_MAX_S = 1.0
LOSS_WINDOW_S = 0.02
SWITCH_OFF_S = 0.03
SWITCH_ON_S = 0.06
LEVEL_S = 0.01


def scenario_skip_s(name, t_end_s):
    """
    Return the leading time (s) left out of the tracking metrics of a scenario.

    As ``fiber-align simulate`` (:func:`fiber_align.simulation.simulate.tracking_skip_s`):
    step and staircase the first half of the run; sine and triangle one period, or
    nothing when the run (``t_end_s``, s) is not longer than that.
    """
    return tracking_skip_s(scenarios.make(name), np.array([0.0, float(t_end_s)]))


def scenario_metrics(name, t, r, y, v=None):
    """
    Return step and tracking metrics (SI) of a measured trace.

    Computed by :func:`fiber_align.simulation.metrics.loop_metrics`, the function
    ``fiber-align analyze`` and ``fiber-align simulate`` use, with the ``analyze``
    settings of ``config/recorder.yaml``: the worst settling time (2 % band), overshoot
    and rise time over the setpoint steps, and the tracking errors after
    :func:`scenario_skip_s`.
    """
    ap = default_params()
    lm = loop_metrics(t, r, y, v, skip_s=scenario_skip_s(name, float(t[-1] - t[0])),
                      **step_settings(ap))
    out = run_scores(lm)
    if name not in ('step', 'staircase'):
        out = {k: v for k, v in out.items() if k not in STEP_KEYS}
    out.update(lm.get('tracking', {}))      # with mean_error_m
    return {k: float(v) for k, v in out.items() if isinstance(v, (int, float))}


def align_metrics(t, y, p, states, events, plant_params, rate_hz):
    """
    Return the alignment figures of an ``align`` run (SI; losses in dB).

    Losses are true coupling losses of the measured tip position against the slot of the
    optics model (``optics.*`` of ``simulated_actuator``); the 10 nm sensor noise adds
    under 1e-5 dB. The figures are those of :func:`align_figures`.
    """
    link = OpticalLink.from_params(plant_params)
    loss = np.asarray(link.loss_db(t, y), float)
    return align_figures(t, p, loss, states, events, rate_hz)


def align_figures(t, p, loss, states, events, rate_hz):
    """
    Return the alignment figures from per-sample power and loss (SI; losses in dB).

    :param t: sample times (s); :param p: measured optical power (W); :param loss: the
        loss of every sample (dB, against whatever reference the caller chose).
    :param states: ``[(sample index, status dict)]`` of ``alignment_state``, each holding
        from its index on.
    :param events: sample indices: ``align`` (the align command), ``tracking`` (first
        TRACKING after it), ``cycles`` (``(off, on, end)`` per switch cycle).
    :param rate_hz: sample rate (Hz).

    ``time_to_first_light_s``: from ``align`` to the first power at or above the
    sequencer's threshold; ``time_to_peak_s``: from ``align`` to TRACKING;
    ``final_loss_db``: mean over the first 20 ms of TRACKING; per switch cycle the loss
    over the last 10 ms of the on time and the 10-90 % rise of the measured power;
    ``tracking_max_loss_db``: the largest loss while TRACKING.
    """
    loss = np.asarray(loss, float)
    period = 1.0 / rate_hz
    n_win, n_lvl = int(round(LOSS_WINDOW_S * rate_hz)), int(round(LEVEL_S * rate_hz))
    out = {'states': [[int(k), st.get('state')] for k, st in states],
           'state': states[-1][1].get('state') if states else None,
           'fault_reason': states[-1][1].get('fault_reason') if states else None}
    ka, kt = events.get('align'), events.get('tracking')
    if ka is not None:
        thr = next((st.get('threshold_w') for _, st in states if st.get('threshold_w')), None)
        if thr:
            lit = np.flatnonzero(np.asarray(p[ka:]) >= thr)
            out['time_to_first_light_s'] = float(lit[0] * period) if lit.size else None
    if ka is not None and kt is not None:
        out['time_to_peak_s'] = float((kt - ka) * period)
        out['final_loss_db'] = float(np.mean(loss[kt:kt + n_win]))
        tr = next((st for k, st in states if k >= kt and st.get('state') == 'TRACKING'), {})
        out['peak_samples'] = tr.get('peak_samples')
        if tr.get('sample') is not None and tr.get('align_sample') is not None:
            # a counted sequencer (multi-axis) names the updates: command to the one that
            # entered TRACKING, as offline (its SEARCHING came between two updates)
            out['time_to_peak_s'] = float((tr['sample'] - 1 - tr['align_sample']) * period)
    cyc = []
    for k_off, k_on, k_end in events.get('cycles', []):
        lo = float(np.mean(p[max(k_on - n_lvl, k_off):k_on]))
        hi = float(np.mean(p[max(k_end - n_lvl, k_on):k_end]))
        cyc.append({'loss_db': float(np.mean(loss[max(k_end - n_lvl, k_on):k_end])),
                    'rise_time_s': rise_time(t[k_on:k_end], p[k_on:k_end], lo, hi)})
    if cyc:
        out['cycles'] = cyc
        out['cycle_loss_max_db'] = max(c['loss_db'] for c in cyc)
        rises = [c['rise_time_s'] for c in cyc if c['rise_time_s'] is not None]
        out['switch_rise_time_max_s'] = max(rises) if rises else None
    tracking = np.zeros(t.size, bool)
    marks = [(int(k), st.get('state')) for k, st in states] + [(t.size, None)]
    for (k0, s0), (k1, _) in zip(marks[:-1], marks[1:]):
        if s0 == 'TRACKING':
            tracking[k0:k1] = True
    if tracking.any():
        out['tracking_max_loss_db'] = float(np.max(loss[tracking]))
    return out


def run_figures(scenario, t, ref, y, series, states, events, plant_params, rate_hz):
    """
    Return the figures of a 1-D run on the graph, by its scenario (``{}``: none).

    :param t, ref, y: the sample times (s), the reference and the position (m).
    :param series: ``key -> per-sample array`` of the other streams (``v``, V; ``p``, W).
    :param states, events, plant_params, rate_hz: as :func:`align_metrics`.
    :returns: ``{'metrics': ...}`` (:func:`scenario_metrics` of a tracking scenario,
        :func:`~fiber_align.analysis.report.hysteresis_metrics` of the open-loop
        experiment) or ``{'align': ...}`` (:func:`align_metrics`); nothing of a run of
        two samples or fewer.
    """
    if t.size <= 2:
        return {}
    if scenario in scenarios.TRACKING:
        return {'metrics': scenario_metrics(scenario, t, ref, y, series('v'))}
    if scenario == 'hysteresis-experiment':
        return {'metrics': hysteresis_metrics(series('v'), y)}
    if scenario == 'align':
        return {'align': align_metrics(t, y, series('p'), states, events, plant_params,
                                       rate_hz)}
    return {}


def format_summary(s):
    """Return the run summary as Markdown text (um, ms, dB for people)."""
    lines = ['', '## bringup summary', '', '| item | value |', '|---|---|']
    for k in ('scenario', 'controller', 'sync_mode', 'rate_hz', 'composed', 'namespace',
              'model_file', 'startup_s', 'run_wall_s', 'samples', 'stop_s', 'record', 'error'):
        if s.get(k) not in (None, ''):
            v = s[k]
            lines.append('| %s | %s |' % (k, '%.3g' % v if isinstance(v, float) else v))
    for k, v in sorted(s.get('metrics', {}).items()):
        if not isinstance(v, (int, float)) or v is None:
            continue
        if k.endswith('_m'):
            lines.append('| %s | %.4g um |' % (k[:-2], v * 1e6))
        elif k.endswith('_s'):
            lines.append('| %s | %.4g ms |' % (k[:-2], v * 1e3))
        elif k.endswith('_v'):
            lines.append('| %s | %.4g V |' % (k[:-2], v))
        else:
            lines.append('| %s | %.4g |' % (k, v))
    al = s.get('align', {})
    for k in ('state', 'fault_reason', 'time_to_first_light_s', 'time_to_peak_s',
              'final_loss_db', 'peak_samples', 'cycle_loss_max_db', 'switch_rise_time_max_s',
              'tracking_max_loss_db'):
        v = al.get(k)
        if v in (None, ''):
            continue
        if k.endswith('_s'):
            lines.append('| align %s | %.4g ms |' % (k[:-2], v * 1e3))
        elif k.endswith('_db'):
            lines.append('| align %s | %.4f dB |' % (k[:-3], v))
        else:
            lines.append('| align %s | %s |' % (k, v))
    for k, v in sorted(s.get('realtime', {}).items()):
        if k.endswith('_s') and isinstance(v, float):
            lines.append('| realtime %s | %.3g ms |' % (k[:-2], v * 1e3))
        elif k == 'missed_share' and isinstance(v, float):
            lines.append('| realtime missed cycles | %.3g %% |' % (100 * v))
        else:
            lines.append('| realtime %s | %s |' % (k, v))
    for name, w in sorted(s.get('cycles', {}).items()):
        if w.get('windows'):
            lines.append('| cycles %s (worst of %d windows) | %.0f Hz, missed %.3g %%, '
                         'p99 %.3g ms |' % (name, w['windows'], w['rate_min_hz'],
                                            100 * w.get('missed_max', 0.0),
                                            1e3 * w.get('p99_max_s', 0.0)))
    for name, u in sorted(s.get('processes', {}).items()):
        cpu = u.get('cpu_per_s')
        lines.append('| process %s | CPU %s s/s, RSS %.0f MB |'
                     % (name, '%.2f' % cpu if cpu is not None else '?', u.get('rss_mb', 0)))
    if s.get('floor'):
        lines.append('| machine floor (bare loop beside the graph) | %s |' % floor_text(
            s['floor']))
    for g in s.get('goals_missed', []):
        lines.append('| GOAL MISSED | %s |' % g)
    for m in s.get('machine_limits', []):
        lines.append('| MACHINE | %s |' % m)
    for node, counts in sorted(s.get('sent', {}).items()):
        if not counts:
            continue
        lines.append('| sent by %s | %s |' % (node, ', '.join(
            '%s=%s' % kv for kv in sorted(counts.items()))))
    if s.get('recorded'):
        lines.append('| recorded | %s |' % ', '.join(
            '%s=%s' % kv for kv in sorted(s['recorded'].items())))
    return '\n'.join(lines)


def _num(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def realtime_figures(diag):
    """
    Return the realtime figures of the run from the nodes' last ``/diagnostics`` values.

    :param diag: node name -> its last key/value pairs (strings) and ``level``.
    :returns: ``missed_share`` (1), ``latency_p50_s``/``latency_p99_s`` (s, sample to
        drive), ``watchdog_count``, ``watchdog_latched``, ``scheduling`` and the
        recorder's ``lost`` count, where reported.
    """
    out = {}
    plant = diag.get('simulated_actuator', {})
    for k in ('missed_share', 'missed_cycles', 'missed_no_drive', 'missed_late_tick',
              'periods', 'latency_p50_s', 'latency_p99_s',
              'latency_max_s', 'achieved_rate_hz'):
        if _num(plant.get(k)) is not None:
            out[k] = _num(plant[k])
    drv = diag.get('actuator_driver', {})
    if _num(drv.get('watchdog_count')) is not None:
        out['watchdog_count'] = int(_num(drv['watchdog_count']))
    if 'watchdog_latched' in drv:
        out['watchdog_latched'] = drv['watchdog_latched'] == 'True'
    if 'scheduling' in plant:
        out['scheduling'] = plant['scheduling']
    rec = diag.get('bag_recorder', {})
    for k in ('lost', 'incompatible_qos'):
        if _num(rec.get(k)) is not None:
            out['recorder_' + k] = int(_num(rec[k]))
    return out


def worst_cycles(worst, node, values):
    """
    Fold one ``/diagnostics`` report of ``node`` into its worst cycle window so far.

    :param worst: node -> ``{'rate_min_hz', 'missed_max', 'p99_max_s', 'windows'}``
        (updated in place).
    :param values: the report's key/value pairs (strings, ``cycle.*`` keys of
        :mod:`fiber_align.control.cycle`); the caller passes only reports of windows
        inside the run.
    """
    rate = _num(values.get('cycle.achieved_rate_hz'))
    if rate is None:
        return
    w = worst.setdefault(node, {'windows': 0})
    w['windows'] += 1
    w['rate_min_hz'] = min(w.get('rate_min_hz', rate), rate)
    for key, out in (('cycle.missed_share', 'missed_max'), ('cycle.latency_p99_s',
                                                            'p99_max_s')):
        v = _num(values.get(key))
        if v is not None:
            w[out] = max(w.get(out, v), v)


def floor_text(floor):
    """
    Return one line of the machine-floor probe's figures (its error if it had none).

    :param floor: the probe's figures (:mod:`fiber_align.control.floor_probe`'s JSON:
        ``lost_share``, ``periods``, ``stalls``, ``worst_stall_s`` (s), ``scheduling``,
        ``work_median_s`` (s)) or ``{'error': text}``.
    """
    if 'error' in floor:
        return floor['error']
    work = floor.get('work_median_s')
    return 'lost %.3g %% of %s periods, %s stalls, the longest %.0f ms, %s; its fixed work ' \
        'took %s' % (100 * floor['lost_share'], floor.get('periods', '?'),
                     floor.get('stalls', '?'), 1e3 * floor.get('worst_stall_s', 0),
                     floor.get('scheduling', '?'), '%.1f us' % (1e6 * work) if work else '?')


def beyond_floor(missed_share, floor):
    """
    Return the share of the periods the graph missed beyond what the machine allowed.

    :param missed_share: the plant's missed share (1) or ``None``.
    :param floor: the machine-floor probe's figures of the same seconds
        (:meth:`fiber_align.control.deadline.DeadlineGrid.figures`: ``lost_share``) or ``None``.
    :returns: ``max(0, missed_share - lost_share)``; ``None`` without both figures.
    """
    fl = _num((floor or {}).get('lost_share'))
    if missed_share is None or fl is None:
        return None
    return max(0.0, float(missed_share) - fl)


def machine_limit(s, sync, missed_goal):
    """
    Return why the machine itself kept the run from its cycle goal, or ``None``.

    The goal (at most ``missed_goal`` of the periods missed) counts against the graph
    only beyond the periods the machine-floor probe lost in the same seconds: a virtual
    machine whose CPUs all stop at once takes those periods from any program. The
    summary prints this line (``MACHINE``) where it applies; ``--strict`` does not fail
    on it.
    """
    ms = s.get('realtime', {}).get('missed_share')
    fl = s.get('floor') or {}
    beyond = beyond_floor(ms, fl)
    if sync != 'realtime' or missed_goal <= 0 or beyond is None or ms <= missed_goal \
            or beyond > missed_goal:
        return None
    return ('missed %.3g %% of the cycles (goal <= %.3g %%), %.3g %% beyond the machine\'s '
            'floor: a bare loop beside the graph lost %.3g %% of its periods in the same '
            'seconds (%d stalls, the longest %.0f ms)' % (
                100 * ms, 100 * missed_goal, 100 * beyond, 100 * fl['lost_share'],
                fl.get('stalls', 0), 1e3 * fl.get('worst_stall_s', 0.0)))


def goals_missed(s, sync, missed_goal):
    """
    Return the realtime goals the run missed, one text each (``[]``: none).

    Realtime: at most ``missed_goal`` of the cycles missed beyond the machine's floor
    (:func:`beyond_floor`; all of them without a floor; ``missed_goal`` <= 0: no such
    goal), no watchdog trip; both modes:
    every message a node sent is in the bag (when recording; a recording that stopped
    early, its disk full, is one goal missed: its tail is not in the bag by design).
    """
    out = []
    rt = s.get('realtime', {})
    if sync == 'realtime':
        ms = rt.get('missed_share')
        beyond = beyond_floor(ms, s.get('floor'))
        if missed_goal > 0 and ms is not None and ms > missed_goal and (
                beyond is None or beyond > missed_goal):
            out.append('missed %.3g %% of the cycles (goal <= %.3g %%)%s'
                       % (100 * ms, 100 * missed_goal, '' if beyond is None else
                          ', %.3g %% beyond the machine\'s floor' % (100 * beyond)))
        if rt.get('watchdog_count'):
            out.append('%d watchdog trip(s)' % rt['watchdog_count'])
    rec = s.get('recorded')
    if s.get('recording_stopped_early'):
        out.append('the bag ends early: recording stopped (the recorder\'s line above)')
    elif rec:
        for node, counts in s.get('sent', {}).items():
            for topic, n in counts.items():
                key = '/' + topic.lstrip('/')
                if key in rec and rec[key] < n:
                    out.append('%s: %d of %d messages of %s recorded'
                               % (key, rec[key], n, node))
    return out


#: Lockstep equality bounds: positions and setpoints (m), power (relative). The graph
#: computes the offline run's operations on the same float64 inputs in the same order
#: (the messages carry float64), so the runs are equal to the last bit; the bounds only
#: leave room for a last-bit difference, far below any physical effect.
TOLERANCE_M = 1e-15
TOLERANCE_REL = 1e-12
#: The offline run a lockstep multi-axis graph equals, by its scenario: ``seed -> bench``
#: (recording its trace) and the bench's align run (the array: the joint method).
OFFLINE = {'align2d': (lambda seed: a2.build(seed=seed, record=True), a2.align_bench),
           'station': (lambda seed: sc.build(seed, record=True), sc.align_bench),
           'array': (lambda seed: asc.build(seed, record=True), hs.align_bench)}


def compare_offline(scenario, seed, align_sample, graph):
    """
    Run the offline ``scenario`` with ``align`` before sample ``align_sample``; compare.

    :param scenario: a key of :data:`OFFLINE` (``align2d``, ``station``, ``array``).
    :param graph: the graph's per-sample arrays, keyed by the offline trace's columns
        (``graph.rig.Machine.streams``): measured positions and setpoints (m), powers
        (``p``, ``p_1``, ...; W).
    :returns: dict: ``samples`` compared, ``max_abs_<stream>`` (m, W), ``max_rel_p``,
        ``equal`` (within :data:`TOLERANCE_M` / :data:`TOLERANCE_REL`), the offline
        ``state`` and ``offline_samples``.
    """
    build, align = OFFLINE[scenario]
    bench = build(seed)
    res = align(bench, idle_s=align_sample * bench.period_s)
    return _compare(bench.trace(), res, graph, tuple(graph))


def _compare(tr, res, graph, streams):
    n = min(tr['t'].size, min(v.size for v in graph.values()))
    out = {'samples': int(n), 'offline_samples': int(tr['t'].size),
           'state': res['state'], 'time_to_peak_s': res['time_to_peak_s'],
           'peak_samples': res['peak_samples'], 'final_loss_db': res['final_loss_db']}
    equal = n == tr['t'].size
    for k in streams:
        d = np.abs(graph[k][:n] - tr[k][:n])
        out['max_abs_' + k] = float(d.max()) if n else math.nan
        if k == 'p' or k.startswith('p_'):          # W: relative
            rel = float((d / np.abs(tr[k][:n])).max()) if n else math.nan
            out['max_rel_p'] = max(out.get('max_rel_p', 0.0), rel)
            equal = equal and rel <= TOLERANCE_REL
        else:
            equal = equal and out['max_abs_' + k] <= TOLERANCE_M
    out['equal'] = bool(equal)
    return out


def write_trace(path, arrays, rate):
    """Write ``k,t_s`` and every stream of ``arrays`` (``<name>_m`` or ``p_w``; SI) to ``path``."""
    n = min(v.size for v in arrays.values())
    k = np.arange(n)
    cols = [k, k / rate] + [arrays[c][:n] for c in arrays]
    head = ['k', 't_s'] + [c + ('_w' if c == 'p' or c.startswith('p_') else '_m')
                           for c in arrays]
    np.savetxt(path, np.column_stack(cols), delimiter=',', fmt='%.17g',
               header=','.join(head), comments='')
