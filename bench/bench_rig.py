# SPDX-License-Identifier: Apache-2.0
"""
The two-axis rig on the ROS graph: ``align2d`` in lockstep against the offline run.

Each row is one ``bringup --rig --seed S`` (the rig of ``fiber_align.graph.rig``,
composed unless ``--multi-process``): in lockstep, the largest difference of every
per-sample stream (both displacements and setpoints, m; the power, relative) from the
offline ``align2d`` with ``align`` before the same sample, the time to peak and peak
samples; in realtime (``--realtime``), the same run without the comparison (the realtime
loop has one period more delay). Wall time per run.

Usage: ``python -m bench.bench_rig [--seeds 10] [--multi-process] [--realtime]
[--json FILE]``. Goal (issue 14): the graph reproduces the offline run (difference 0 to
float rounding).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

BRINGUP = [sys.executable, '-m', 'fiber_align.bringup', '--rig', '--quiet']


def run(seed, sync, multi, timeout=180.0):
    """Run ``bringup --rig`` once; return its summary (dict, SI) with ``wall_s``."""
    with tempfile.TemporaryDirectory(prefix='bench_rig_') as d:
        path = os.path.join(d, 'summary.json')
        cmd = BRINGUP + ['--sync', sync, '--seed', str(seed), '--summary', path]
        if multi:
            cmd.append('--multi-process')
        t0 = time.monotonic()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        out = {'error': proc.stdout[-300:] + proc.stderr[-300:]}
        if os.path.isfile(path):
            with open(path, encoding='utf-8') as f:
                out = json.load(f)
        out.update(wall_s=time.monotonic() - t0, exit_code=proc.returncode)
        return out


def _f(v, fmt='%.3g', scale=1.0):
    return '-' if v is None else fmt % (v * scale)


def main(argv=None):
    """Run the rows, print the table; return 0."""
    ap = argparse.ArgumentParser(prog='bench_rig', description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seeds', type=int, default=10, help='seeds 0..N-1 (10)')
    ap.add_argument('--multi-process', action='store_true', help='one process per node')
    ap.add_argument('--realtime', action='store_true', help='realtime rows too')
    ap.add_argument('--json', help='write the rows (SI) to this file')
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    rows = []
    for sync in ('lockstep',) + (('realtime',) if a.realtime else ()):
        for seed in range(a.seeds):
            rows.append(dict(run(seed, sync, a.multi_process), sync=sync, seed=seed))
    print('| sync | seed | state | align at | time to peak | peak samples | compared | '
          'max diff x, y (m) | max diff setpoints (m) | max rel diff P | equal | wall |')
    print('|---|---|---|---|---|---|---|---|---|---|---|---|')
    for r in rows:
        o = r.get('offline') or {}
        print('| %s | %d | %s | %s | %s ms | %s | %s | %s | %s | %s | %s | %.1f s |' % (
            r['sync'], r['seed'], r.get('state') or r.get('error'), r.get('align_sample'),
            _f(r.get('time_to_peak_s'), '%.1f', 1e3), r.get('peak_samples'),
            o.get('samples', '-'),
            _f(max(o['max_abs_mx'], o['max_abs_my'])) if o else '-',
            _f(max(o['max_abs_rx'], o['max_abs_ry'])) if o else '-',
            _f(o.get('max_rel_p')), o.get('equal', '-'), r['wall_s']), flush=True)
    lock = [r for r in rows if r['sync'] == 'lockstep']
    print('\nlockstep: %d of %d runs equal the offline run'
          % (sum(1 for r in lock if (r.get('offline') or {}).get('equal')), len(lock)))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump(rows, f, indent=2, default=str)
    return 0


if __name__ == '__main__':
    sys.exit(main())
