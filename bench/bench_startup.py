# SPDX-License-Identifier: Apache-2.0
"""
Lockstep start-ups in a row: how often the multi-process graph stalls at its first sample.

Before the per-sample topics became transient local, about one multi-process lockstep
start in four lost its first message in the discovery race and stalled (``bringup``
restarted the graph). This runs ``bringup --multi-process --sync lockstep --scenario
step --duration 0.05`` ``--runs`` times (30) and counts the restarts, the failures and
the start-up times.

Usage: ``python -m bench.bench_startup [--runs 30] [--composed]``.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np


def main(argv=None):
    """Run the start-ups; print the counts."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--runs', type=int, default=30)
    ap.add_argument('--composed', action='store_true')
    a = ap.parse_args(argv)
    restarts, failures, startup = 0, 0, []
    with tempfile.TemporaryDirectory(prefix='bench_startup_') as tmp:
        for i in range(a.runs):
            summary = os.path.join(tmp, '%d.json' % i)
            cmd = [sys.executable, '-m', 'fiber_align.bringup', '--sync', 'lockstep',
                   '--scenario', 'step', '--duration', '0.05', '--quiet', '--summary', summary,
                   '--composed' if a.composed else '--multi-process']
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
            s = json.load(open(summary)) if os.path.isfile(summary) else {}
            restarts += int(s.get('restarts', 0))
            failures += int(p.returncode != 0)
            if 'startup_s' in s:
                startup.append(s['startup_s'])
    print('| layout | runs | restarts | failures | start-up median / max (s) |')
    print('|---|---|---|---|---|')
    print('| %s | %d | %d | %d | %.2f / %.2f |' % (
        'composed' if a.composed else 'multi-process', a.runs, restarts, failures,
        float(np.median(startup)) if startup else float('nan'),
        max(startup) if startup else float('nan')))
    return 0


if __name__ == '__main__':
    sys.exit(main())
