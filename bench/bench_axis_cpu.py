# SPDX-License-Identifier: Apache-2.0
"""
CPU per axis of the realtime graph: this tree beside a baseline tree, in one run.

Each run is one ``bringup --sync realtime`` (the graph users start with ``ros2 launch``):
the 1-D graph on a sine (``--scenario sine``, one axis), with or without a recorder, and
the two-axis rig aligning, through ``--rig-cycles`` release / align cycles, then held
aligned for ``--seconds`` (``--rig --cycles N --duration S``, two axes), and the same
for the coupled station with its recorder (``--station ... --record``, four axes); and
``one-launch`` / ``one-launch-recorded``: the 1-D graph started as ``ros2 launch`` starts
it, with nothing watching (:mod:`bench.graph_cpu`; CPU only: bringup's observer of the
1-D run is the one DDS reader of two 1 kHz topics, a load the launched graph does not
carry). The
trees alternate run by run (A, B, A, B, ...) so both see the same machine; every
process of the graph is counted (CPU seconds per second of run, from bringup's
summary), divided by the axes.
Reported per case and tree: the median and the spread of CPU per axis and of the cycles
kept (the worst axis), watchdog trips and failed runs, and the ratio of the medians (this
tree over the baseline).

Usage: ``python -m bench.bench_axis_cpu --baseline DIR [--repeats 3] [--seconds 20]
[--rig-cycles 20] [--cases one,one-recorded,one-launch,one-launch-recorded,rig,station,array]
[--json FILE]``; ``DIR`` is a checkout of
the baseline (e.g. ``git worktree add --detach /tmp/base <commit>``). ``--baseline-args``
gives the baseline's runs more ``bringup`` options: with ``--baseline .`` one tree against
itself with one setting changed, e.g. ``--baseline-args="-p **:cpu_idle_poll:=false"``
(docs/realtime.md). Beside each run: the machine-floor probe's lost share (the bare
loop that runs beside every realtime run), so a setting that costs the machine shows.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: case -> (bringup arguments, axes, recorded)
CASES = {
    'one': (['--scenario', 'sine', '--duration', '{seconds}'], 1, False),
    'one-recorded': (['--scenario', 'sine', '--duration', '{seconds}'], 1, True),
    'rig': (['--rig', '--cycles', '{cycles}', '--duration', '{seconds}'], 2, False),
    # the coupled station with its recorder (a tree without --station: failed runs)
    'station': (['--station', '--cycles', '{cycles}', '--duration', '{seconds}'], 4, True),
    # the fiber array (x, y_left, y_right) with its recorder, seed 2 as docs/array.md
    'array': (['--array', '--seed', '2', '--cycles', '{cycles}', '--duration', '{seconds}'],
              3, True),
    # the 1-D graph as `ros2 launch` starts it, nothing watching (bench/graph_cpu.py):
    # bringup's observer of the 1-D run takes two 1 kHz topics over DDS from the graph
    'one-launch': (None, 1, False),
    'one-launch-recorded': (None, 1, True),
}


def run_once(tree, case, seconds, tmp, cycles=20, extra=()):
    """Run one case on ``tree`` (``extra``: more bringup options); return its figures."""
    args, axes, recorded = CASES[case]
    if args is None:
        return run_launched(tree, seconds, axes, recorded)
    summary = os.path.join(tmp, 'summary-%s-%s.json' % (case, os.getpid()))
    if os.path.exists(summary):
        os.remove(summary)
    # a baseline tree from before the harness left nodes/ has it at fiber_align.nodes.bringup
    harness = 'fiber_align.bringup' if os.path.isdir(
        os.path.join(tree, 'fiber_align', 'bringup')) else 'fiber_align.nodes.bringup'
    cmd = [sys.executable, '-m', harness] + [
        x.format(seconds=seconds, cycles=cycles) for x in args] + [
        '--sync', 'realtime', '--quiet', '--summary', summary] + list(extra)
    if recorded:
        bag = tempfile.mkdtemp(dir=tmp)
        os.rmdir(bag)
        cmd += ['--record', bag]
    env = dict(os.environ, PYTHONPATH=tree)
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tree,
                          timeout=180 + 3 * seconds + 3 * cycles)
    if not os.path.isfile(summary):
        return {'error': (proc.stdout + proc.stderr)[-400:]}
    with open(summary, encoding='utf-8') as f:
        s = json.load(f)
    cpu = sum(p.get('cpu_per_s') or 0.0 for p in s.get('processes', {}).values())
    shares = [a.get('missed_share') for a in _axes(s) if a.get('missed_share') is not None]
    return {'cpu_per_axis': cpu / axes, 'cpu_total': cpu,
            'cycles_kept': 1.0 - max(shares) if shares else None,
            'processes': {k: v.get('cpu_per_s') for k, v in s.get('processes', {}).items()},
            'trips': sum(int(a.get('watchdog_count') or 0) for a in _axes(s)),
            'recorder_short': s.get('recorder_short'),
            'floor_lost_share': (s.get('floor') or {}).get('lost_share'),
            'state': s.get('state'), 'error': s.get('error') or None,
            'exit_code': proc.returncode}


def run_launched(tree, seconds, axes, recorded):
    """Run ``bench/graph_cpu.py`` on ``tree``; return its CPU figures (no cycles)."""
    cmd = [sys.executable, os.path.join(ROOT, 'bench', 'graph_cpu.py'),
           '--seconds', str(seconds)] + (['--record'] if recorded else [])
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tree,
                          env=dict(os.environ, PYTHONPATH=tree), timeout=120 + 2 * seconds)
    try:
        out = json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {'error': (proc.stdout + proc.stderr)[-400:]}
    cpu = sum(out['processes'].values())
    ran = not recorded or min(out['recorded'].get('/displacement', 0), 1) > 0
    return {'cpu_per_axis': cpu / axes, 'cpu_total': cpu, 'cycles_kept': None,
            'processes': out['processes'], 'trips': 0, 'floor_lost_share': None,
            'error': None if ran else 'nothing recorded', 'exit_code': proc.returncode}


def _axes(s):
    """Return the realtime figures of each axis in a bringup summary."""
    if 'axes' in s and isinstance(s['axes'], dict):
        return [a.get('realtime', a) for a in s['axes'].values()]
    return [s.get('realtime', {})]


def summarise(runs):
    """Return the median, min and max of each figure over ``runs``."""
    out = {}
    for key in ('cpu_per_axis', 'cycles_kept', 'floor_lost_share'):
        v = [r[key] for r in runs if r.get(key) is not None]
        out[key] = {'median': float(np.median(v)), 'min': min(v), 'max': max(v)} if v \
            else None
    out['errors'] = [r['error'] for r in runs if r.get('error')]
    out['trips'] = sum(r.get('trips') or 0 for r in runs)
    return out


def main(argv=None):
    """Run the comparison; print the table (and write JSON with ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--baseline', required=True, help='checkout of the baseline tree')
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--seconds', type=float, default=20.0)
    ap.add_argument('--rig-cycles', type=int, default=20,
                    help='rig: release / align cycles before the held part')
    ap.add_argument('--cases', default='one,one-recorded,rig')
    ap.add_argument('--baseline-args', default='',
                    help='more bringup options for the baseline runs (one string)')
    ap.add_argument('--this-args', default='',
                    help="more bringup options for this tree's runs (one string), e.g. "
                         "'--catalog none' to compare the graph without its catalogue")
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    trees = {'this': ROOT, 'baseline': os.path.abspath(a.baseline)}
    cases = [c for c in a.cases.split(',') if c]
    runs = {(c, t): [] for c in cases for t in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeats):
            for c in cases:
                for t in ('this', 'baseline'):
                    runs[(c, t)].append(run_once(
                        trees[t], c, a.seconds, tmp, a.rig_cycles,
                        (a.baseline_args if t == 'baseline' else a.this_args).split()))
    out = {'seconds': a.seconds, 'repeats': a.repeats, 'load_average': os.getloadavg(),
           'baseline_args': a.baseline_args, 'this_args': a.this_args,
           'cases': {}}
    lines = ['| case | tree | CPU per axis (s/s) median [min, max] | cycles kept, worst axis '
             '(median) [min] | floor lost, median [min, max] | trips | failed runs |',
             '|---|---|---|---|---|---|---|']
    for c in cases:
        out['cases'][c] = {t: dict(summarise(runs[(c, t)]), runs=runs[(c, t)]) for t in trees}
        for t in trees:
            s = out['cases'][c][t]
            cpu, cyc, fl = s['cpu_per_axis'], s['cycles_kept'], s['floor_lost_share']
            lines.append('| %s | %s | %s | %s | %s | %d | %d |' % (
                c, t, '%.3f [%.3f, %.3f]' % (cpu['median'], cpu['min'], cpu['max'])
                if cpu else 'error', '%.3f %% [%.3f %%]' % (100 * cyc['median'],
                                                            100 * cyc['min'])
                if cyc else '-', '%.3f %% [%.3f, %.3f]' % (
                    100 * fl['median'], 100 * fl['min'], 100 * fl['max']) if fl else '-',
                s['trips'], len(s['errors'])))
        a_, b_ = out['cases'][c]['this']['cpu_per_axis'], \
            out['cases'][c]['baseline']['cpu_per_axis']
        if a_ and b_:
            out['cases'][c]['ratio_cpu'] = a_['median'] / b_['median']
            lines.append('| %s | this / baseline | %.2f | | | | |'
                         % (c, out['cases'][c]['ratio_cpu']))
    print('\n'.join(lines))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
