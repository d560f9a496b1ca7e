# SPDX-License-Identifier: Apache-2.0
"""
Realtime ROS graph benchmark: the 1 kHz loop as users run it, beside its baselines.

Each row is one ``bringup --scenario sine --sync realtime --duration S --record DIR``
(the pip way to start the graph that ``ros2 launch`` starts, from the one graph
description of ``fiber_align.graph.description``), in the composed layout (the default) and
with ``--multi-process``. Measured beside them in the same run:

- the machine's floor: how late a bare Python loop (``time.sleep`` to each deadline,
  no ROS) wakes for 1 kHz ticks, at normal priority and at the graph's SCHED_FIFO
  priority (:func:`machine_floor`);
- the lockstep run of the same scenario: the tracking RMS a realtime run is held to
  (goal: within 2x).

Per row: cycles kept (share of sample periods with a fresh drive), the periods the
machine itself lost over the same seconds (bringup's machine-floor probe, a bare loop
beside the graph, counted by the plant's rule) and what the graph missed beyond them,
missed cycles,
sample-to-drive latency p50/p99 (ms, the plant's own measurement), tracking RMS and its
ratio to lockstep, watchdog trips, whether the bag holds exactly what every publisher
sent, and CPU (s per s of run) and resident memory (MB) per process. ``--hogs N`` adds
N busy loops (``python3 -c 'while True: pass'``) for the whole run.

Usage: ``python -m bench.bench_graph [--seconds 60] [--hogs 2] [--baseline DIR]
[--repeats N] [--json FILE]``; with ``--baseline`` every row is followed by the same run
of the checkout ``DIR`` (an older commit), so the two share the machine's state.
Goals (issue 10): >= 99.9 % cycles, RMS <= 2x lockstep, no trip, nothing lost,
latency p99 <= 2x the bare loop's lateness p99.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from fiber_align.analysis.run_summary import beyond_floor
from fiber_align.hardware.process import stop_process

BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']


_SLEEP_LOOP = (
    'T=1.0/rate; n=int(seconds/T)\n'
    't0=time.perf_counter()\n'
    'for k in range(n):\n'
    '    dl=t0+(k+1)*T; d=dl-time.perf_counter()\n'
    '    if d>0: time.sleep(d)\n'
    '    lat.append(time.perf_counter()-dl)\n')
# the same loop on an rclpy timer of the C++ events executor, as the plant ticks: the
# executor's timer thread wakes, hands the timer to the executor thread, which calls
# back; a deadline the timer skipped counts as late from the first skipped one
_RCLPY_LOOP = (
    'import rclpy\n'
    'from rclpy.clock import Clock, ClockType\n'
    'from rclpy.experimental import EventsExecutor\n'
    'rclpy.init(); node=rclpy.create_node("bench_floor"); T=1.0/rate; st={}\n'
    'for tid in os.listdir("/proc/self/task"):\n'
    '    p and os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(p))\n'
    'ex=EventsExecutor(); ex.add_node(node)\n'
    'def cb():\n'
    '    now=time.perf_counter(); s=now+tm.time_until_next_call()*1e-9-T\n'
    '    prev=st.get("prev"); st["prev"]=s\n'
    '    lat.append(now-(prev+T if prev is not None else s))\n'
    'tm=node.create_timer(T, cb, clock=Clock(clock_type=ClockType.STEADY_TIME))\n'
    'end=time.monotonic()+seconds\n'
    'while time.monotonic()<end: ex.spin_once(timeout_sec=0.1)\n'
    'node.destroy_node(); rclpy.try_shutdown()\n')


def machine_floor(seconds=5.0, rate_hz=1000.0, priority=0, timer='sleep'):
    """
    Return how late a bare Python loop wakes for ``rate_hz`` ticks (s percentiles).

    :param priority: SCHED_FIFO priority of the loop's process (0: normal).
    :param timer: ``sleep`` (``time.sleep`` to each deadline) or ``rclpy`` (an rclpy
        timer of the events executor, every thread at ``priority``).
    """
    code = ('import time,os,sys,json\n'
            'seconds=float(sys.argv[1]); rate=float(sys.argv[2]); p=int(sys.argv[3]); lat=[]\n'
            'if p: os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(p))\n'
            + (_RCLPY_LOOP if timer == 'rclpy' else _SLEEP_LOOP)
            + 'print(json.dumps(lat))\n')
    out = subprocess.run([sys.executable, '-c', code, str(seconds), str(rate_hz),
                          str(priority)], capture_output=True, text=True, timeout=seconds + 60)
    if out.returncode != 0:
        return {'error': out.stderr.strip().splitlines()[-1:]}
    lat = np.array(json.loads(out.stdout.strip().splitlines()[-1]))
    return {'p50_s': float(np.percentile(lat, 50)), 'p99_s': float(np.percentile(lat, 99)),
            'late_1ms_share': float(np.mean(lat > 1.0 / rate_hz)), 'priority': priority,
            'timer': timer, 'ticks': int(lat.size)}


def run_bringup(tmp, tag, seconds, sync, extra=(), tree=None):
    """
    Run one bringup; return its summary dict (``error`` set on a failure).

    :param tree: a checkout whose ``fiber_align`` runs (``python -m`` takes it from the
        working directory); ``None``: this one.
    """
    bag = os.path.join(tmp, tag + '_bag')
    summary = os.path.join(tmp, tag + '.json')
    head = BRINGUP
    if tree and not os.path.isdir(os.path.join(tree, 'fiber_align', 'bringup')):
        head = BRINGUP[:2] + ['fiber_align.nodes.bringup']     # a tree from before the move
    cmd = head + ['--scenario', 'sine', '--sync', sync, '--duration', str(seconds),
                  '--quiet', '--summary', summary] + list(extra)
    if sync == 'realtime':
        cmd += ['--record', bag]
    limit = 120 + 3 * seconds
    log = os.path.join(tmp, tag + '.log')
    with open(log, 'w', encoding='utf-8') as f:
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, text=True, cwd=tree)
    try:
        proc.wait(timeout=limit)
        timed_out = False
    except subprocess.TimeoutExpired:
        stop_process(proc, grace_s=20.0)        # bringup's own bounded stop first
        timed_out = True
    with open(log, encoding='utf-8') as f:
        out = f.read()
    if timed_out:
        return {'error': 'no result within %g s (stopped): %s' % (limit, out[-300:])}
    if not os.path.isfile(summary):
        return {'error': out[-500:]}
    with open(summary, encoding='utf-8') as f:
        s = json.load(f)
    s['exit_code'] = proc.returncode
    return s


def _complete(s):
    """Return True when the bag holds exactly what every node sent on recorded topics."""
    rec = s.get('recorded') or {}
    if not rec:
        return None
    for node, counts in s.get('sent', {}).items():
        for topic, n in counts.items():
            key = '/' + topic.lstrip('/')
            if key in rec and rec[key] != n:
                return False
    return not s.get('recorder_short')


def row(tag, s, lockstep_rms, floor_p99):
    """Return the table figures of one run."""
    rt = s.get('realtime', {})
    ms = rt.get('missed_share')
    rms = s.get('metrics', {}).get('rms_error_m')
    p99 = rt.get('latency_p99_s')
    fl = s.get('floor') or {}
    return {'run': tag, 'cycles_kept': None if ms is None else 1.0 - ms,
            'floor_lost_share': fl.get('lost_share'),
            'beyond_floor_share': beyond_floor(ms, fl),
            'missed_cycles': rt.get('missed_cycles'), 'latency_p50_s': rt.get('latency_p50_s'),
            'latency_p99_s': p99, 'latency_p99_over_floor': (p99 / floor_p99)
            if p99 and floor_p99 else None, 'rms_m': rms,
            'rms_over_lockstep': rms / lockstep_rms if rms and lockstep_rms else None,
            'watchdog_trips': rt.get('watchdog_count'), 'bag_complete': _complete(s),
            'processes': s.get('processes', {}), 'scheduling': rt.get('scheduling'),
            'error': s.get('error')}


def table(rows, floors):
    """Return the Markdown table of the rows and the machine floors."""
    def f(v, scale=1.0, fmt='%.3g'):
        return '-' if v is None else fmt % (v * scale)
    lines = ['| run | cycles kept | the machine lost (bare loop beside it) | missed beyond '
             'it | latency p50 / p99 (ms) | p99 / bare loop p99 | RMS (um) | RMS / lockstep '
             '| trips | bag complete | CPU s/s, RSS MB per process |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        procs = ', '.join('%s %.2f / %.0f' % (k, v.get('cpu_per_s') or 0, v.get('rss_mb', 0))
                          for k, v in sorted(r['processes'].items()))
        lines.append('| %s | %s %% | %s %% | %s %% | %s / %s | %s | %s | %s | %s | %s | %s |' % (
            r['run'], f(r['cycles_kept'], 100, '%.2f'), f(r['floor_lost_share'], 100),
            f(r['beyond_floor_share'], 100), f(r['latency_p50_s'], 1e3),
            f(r['latency_p99_s'], 1e3), f(r['latency_p99_over_floor'], 1, '%.2f'),
            f(r['rms_m'], 1e6, '%.3f'), f(r['rms_over_lockstep'], 1, '%.2f'),
            r['watchdog_trips'], r['bag_complete'], procs or r.get('error') or '-'))
    lines.append('')
    lines.append('| bare 1 kHz Python loop | lateness p50 / p99 (ms) | > 1 ms late |')
    lines.append('|---|---|---|')
    for fl in floors:
        lines.append('| %s, priority %s, %s ticks | %s / %s | %s %% |' % (
            fl.get('timer', 'sleep'), fl.get('priority'), fl.get('ticks'),
            f(fl.get('p50_s'), 1e3), f(fl.get('p99_s'), 1e3),
            f(fl.get('late_1ms_share'), 100, '%.3f')))
    return '\n'.join(lines)


def main(argv=None):
    """Run the benchmark; print the table (and write JSON with ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seconds', type=float, default=10.0)
    ap.add_argument('--hogs', type=int, default=0, help='busy loops beside the graph')
    ap.add_argument('--layouts', default='composed,multi-process')
    ap.add_argument('--json', default=None)
    ap.add_argument('--floor-seconds', type=float, default=10.0,
                    help='length of each bare-loop baseline (s)')
    ap.add_argument('--baseline', default=None,
                    help='a checkout of an older commit: each layout runs there too, '
                         'right after this tree\'s run')
    ap.add_argument('--repeats', type=int, default=1, help='runs of each layout (and tree)')
    a = ap.parse_args(argv)
    trees = [('this', None)] + ([('baseline', os.path.abspath(a.baseline))]
                                if a.baseline else [])
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(a.hogs)]
    try:
        with tempfile.TemporaryDirectory(prefix='bench_graph_') as tmp:
            lock = run_bringup(tmp, 'lockstep', a.seconds, 'lockstep')
            lock_rms = lock.get('metrics', {}).get('rms_error_m')
            floors = [machine_floor(a.floor_seconds, priority=0),
                      machine_floor(a.floor_seconds, priority=50),
                      machine_floor(a.floor_seconds, priority=50, timer='rclpy')]
            rows = []
            for k in range(a.repeats):
                for layout in a.layouts.split(','):
                    extra = ['--multi-process'] if layout == 'multi-process' else []
                    for name, tree in trees:
                        tag = '%s-%s-%d' % (name, layout, k)
                        s = run_bringup(tmp, tag, a.seconds, 'realtime', extra, tree)
                        rows.append(row('%s%s, %d hog(s)' % (
                            '' if len(trees) == 1 else name + ': ', layout, a.hogs), s,
                            lock_rms, floors[1].get('p99_s')))
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    print('lockstep RMS %.4f um; load average %s' % (
        (lock_rms or float('nan')) * 1e6, os.getloadavg()))
    print(table(rows, floors))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump({'rows': rows, 'floors': floors, 'lockstep_rms_m': lock_rms,
                       'seconds': a.seconds, 'hogs': a.hogs, 'time': time.time()}, f,
                      indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
