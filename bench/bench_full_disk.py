# SPDX-License-Identifier: Apache-2.0
"""
Periods kept by a realtime run recording into a full 5 MB filesystem, beside unrecorded.

Each pair is ``bringup --scenario sine --sync realtime --duration S`` unrecorded, then the
same with ``--record`` into a fresh 5 MB tmpfs (mounted with mount(2): root), for this
tree and, alternating, a baseline tree. Printed: the share of the periods missed beyond
the machine's floor (the floor probe's own losses) per run, and the medians.

Usage (root): ``python -m bench.bench_full_disk --baseline DIR [--pairs 3] [--seconds 30]``
(``DIR`` a checkout, e.g. ``git worktree add --detach /tmp/base <commit>``).
"""

import argparse
import ctypes
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FS_BYTES = 5 * 2 ** 20
MNT_DETACH = 2


def run(tree, seconds, record):
    """Return ``(beyond the floor (share), summary)`` of one run of ``tree``."""
    libc = ctypes.CDLL(None, use_errno=True)
    with tempfile.TemporaryDirectory() as d:
        summary = os.path.join(d, 'summary.json')
        args = [sys.executable, '-m', 'fiber_align.bringup', '--scenario', 'sine', '--sync',
                'realtime', '--duration', str(seconds), '--summary', summary]
        fs = os.path.join(d, 'fs')
        if record:
            os.mkdir(fs)
            if libc.mount(b'tmpfs', fs.encode(), b'tmpfs', 0, b'size=%d' % FS_BYTES) != 0:
                raise SystemExit('a tmpfs needs root: %s' % os.strerror(ctypes.get_errno()))
            args += ['--record', os.path.join(fs, 'bag')]
        try:
            subprocess.run(args, env=dict(os.environ, PYTHONPATH=tree), capture_output=True,
                           timeout=120 + 2 * seconds, check=True)
        finally:
            if record:
                libc.umount2(fs.encode(), MNT_DETACH)
        with open(summary, encoding='utf-8') as f:
            s = json.load(f)
    return s['realtime']['missed_share'] - s['floor']['lost_share'], s


def main(argv=None):
    """Run the pairs; print each run and the medians (percent of the periods)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    ap.add_argument('--baseline', required=True, help='checkout of the baseline tree')
    ap.add_argument('--pairs', type=int, default=3)
    ap.add_argument('--seconds', type=float, default=30.0)
    a = ap.parse_args(argv)
    trees = {'this': ROOT, 'baseline': os.path.abspath(a.baseline)}
    got = {(t, r): [] for t in trees for r in (False, True)}
    for i in range(a.pairs):
        for t, path in trees.items():
            for record in (False, True):
                beyond, s = run(path, a.seconds, record)
                got[t, record].append(100 * beyond)
                print('%s %s: %.3f %% beyond the floor %s' % (
                    t, 'recorded' if record else 'unrecorded', 100 * beyond,
                    s.get('recording_stopped_early', '')[:40]), flush=True)
    for (t, record), v in got.items():
        print('median %s %s: %.3f %% [%.3f, %.3f]' % (
            t, 'recorded' if record else 'unrecorded', statistics.median(v), min(v), max(v)))


if __name__ == '__main__':
    main()
