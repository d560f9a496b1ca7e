# SPDX-License-Identifier: Apache-2.0
"""
Readers that join a running realtime graph: what they cost the loop, this tree beside a baseline.

Each run is one ``bringup --scenario step --sync realtime --duration S`` while a user runs
``ros2 topic echo --once /displacement`` ``--echoes`` times, one a second (each one a
new DDS participant and a reader that takes the durability the publishers offer; a
transient-local writer sends it its whole history). The trees alternate run by run.
Reported per tree: the run's missed cycles and the worst 1 s window of the plant's
``cycle.missed_share`` (bringup's summary), medians over ``--repeats``, and how old the
first sample each echo printed was (s, its stamp against the wall clock).

Usage: ``python -m bench.bench_late_reader --baseline DIR [--repeats 2] [--echoes 12]
[--seconds 40] [--json FILE]``.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench.bench_axis_cpu import ROOT
from bench.bench_soak import ros2_env


def run_once(tree, seconds, echoes, tmp, env):
    """Run the graph on ``tree`` with ``echoes`` echoes; return its figures."""
    summary = os.path.join(tmp, 'summary.json')
    log = os.path.join(tmp, 'bringup.log')
    if os.path.exists(summary):
        os.remove(summary)
    genv = dict(env, PYTHONPATH=tree)
    with open(log, 'w') as f:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'fiber_align.bringup', '--scenario', 'step',
             '--duration', str(seconds), '--sync', 'realtime', '--summary', summary],
            stdout=f, stderr=subprocess.STDOUT, env=genv, cwd=tree)
    ages = []
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and 'graph up' not in open(log).read():
            time.sleep(0.2)
        time.sleep(3.0)
        for _ in range(echoes):
            t = time.time()
            try:
                out = subprocess.run(['ros2', 'topic', 'echo', '--once', '--no-daemon',
                                      '/displacement'], capture_output=True, text=True,
                                     env=env, timeout=20).stdout
                ages.append(t - _stamp(out) if _stamp(out) else None)
            except subprocess.TimeoutExpired:
                ages.append(None)
            time.sleep(1.0)
        proc.wait(timeout=120 + seconds)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if not os.path.isfile(summary):
        return {'error': open(log).read()[-400:]}
    with open(summary, encoding='utf-8') as f:
        s = json.load(f)
    return {'missed_share': s.get('realtime', {}).get('missed_share'),
            'worst_window': s.get('cycles', {}).get('simulated_actuator', {}).get(
                'missed_max'),
            'first_sample_age_s': [a for a in ages if a is not None]}


def _stamp(text):
    """Return the header stamp (s) of an echoed JointState, or None."""
    sec = nsec = None
    for line in text.splitlines():
        line = line.strip()
        if line.startswith('sec:') and sec is None:
            sec = int(line.split(':')[1])
        elif line.startswith('nanosec:') and nsec is None:
            nsec = int(line.split(':')[1])
    return sec + 1e-9 * nsec if sec is not None and nsec is not None else None


def main(argv=None):
    """Run the comparison; print the table (and write JSON with ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--baseline', required=True)
    ap.add_argument('--repeats', type=int, default=2)
    ap.add_argument('--echoes', type=int, default=12)
    ap.add_argument('--seconds', type=float, default=40.0)
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env = ros2_env()
    trees = {'this': ROOT, 'baseline': os.path.abspath(a.baseline)}
    runs = {t: [] for t in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeats):
            for t in trees:
                runs[t].append(run_once(trees[t], a.seconds, a.echoes, tmp, env))
    out = {'runs': runs, 'load_average': os.getloadavg(), 'echoes': a.echoes}
    lines = ['| tree | missed cycles (median) | worst 1 s window (median) | first echoed '
             'sample age, median (s) |', '|---|---|---|---|']
    for t, rs in runs.items():
        ms = [r['missed_share'] for r in rs if r.get('missed_share') is not None]
        ww = [r['worst_window'] for r in rs if r.get('worst_window') is not None]
        ages = [x for r in rs for x in r.get('first_sample_age_s', [])]
        out[t] = {'missed_share': float(np.median(ms)) if ms else None,
                  'worst_window': float(np.median(ww)) if ww else None,
                  'first_sample_age_s': float(np.median(ages)) if ages else None}
        lines.append('| %s | %s | %s | %s |' % (
            t, '%.3f %%' % (100 * out[t]['missed_share']) if ms else '-',
            '%.1f %%' % (100 * out[t]['worst_window']) if ww else '-',
            '%.3f' % out[t]['first_sample_age_s'] if ages else '-'))
    print('\n'.join(lines))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
