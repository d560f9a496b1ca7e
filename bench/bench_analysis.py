# SPDX-License-Identifier: Apache-2.0
"""
Benchmark ``fiber-align analyze`` on a long lockstep bag (default: one hour at 1 kHz).

Generates a bag with every loop topic (clock, displacement, setpoint, feedforward,
feedback, drive, optical power, controller state: 8 topics x rate x duration messages),
then analyses it in a fresh subprocess and reports wall time, messages per second and
the subprocess's peak RSS (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``).

Usage: ``python -m bench.bench_analysis [--quick] [--seconds S] [--storage mcap|sqlite3]
[--keep DIR] [--plots]``. Goals: <= 500 MB peak, > 1e6 messages/s.
"""

import argparse
from pathlib import Path
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

RATE_HZ = 1000.0
PART = 200_000


def _series(n, rate_hz=RATE_HZ):
    """Return write_bag series whose values are made chunk by chunk (bounded memory)."""
    period_ns = int(round(1e9 / rate_hz))
    wall0 = 1_700_000_000_000_000_000

    def parts(make):
        def gen():
            for i0 in range(0, n, PART):
                k = np.arange(i0, min(n, i0 + PART))
                yield make(k)
        return gen

    def stamp(k):
        return k * period_ns

    def wall(k):
        return wall0 + k * period_ns + 137_000 * (k % 3)

    def ref(k):
        # 82 um steps every 2 s between 20 and 82 um
        return np.where((k // int(2 * rate_hz)) % 2 == 0, 20e-6, 82e-6)

    def y(k):
        tk = (k % int(2 * rate_hz)) / rate_hz
        r = ref(k)
        r0 = np.where(r > 50e-6, 20e-6, 82e-6)
        return r + (r0 - r) * np.exp(-tk / 0.004)

    return {
        'clock': parts(lambda k: {'t_ns': wall(k), 'clock_ns': stamp(k)}),
        'displacement': parts(lambda k: {'t_ns': wall(k) + 10_000, 'stamp_ns': stamp(k),
                                         'position': y(k), 'velocity': np.zeros(k.size)}),
        'setpoint': parts(lambda k: {'t_ns': wall(k) + 20_000, 'data': ref(k)}),
        'feedforward_voltage': parts(lambda k: {'t_ns': wall(k) + 30_000,
                                                'data': ref(k) * 1e6}),
        'feedback_voltage': parts(lambda k: {'t_ns': wall(k) + 30_000,
                                             'data': (ref(k) - y(k)) * 1e6}),
        'drive_voltage': parts(lambda k: {'t_ns': wall(k) + 40_000,
                                          'data': np.clip(2e6 * ref(k) - 1e6 * y(k), 0, 100)}),
        'optical_power': parts(lambda k: {'t_ns': wall(k) + 20_000,
                                          'data': 1e-3 * np.exp(-((y(k) - 82e-6) / 5e-6) ** 2)}),
        'controller_state': parts(lambda k: {
            't_ns': wall(k) + 30_000,
            'data': np.column_stack([y(k) - ref(k), np.zeros(k.size), np.full(k.size, 2e5),
                                     np.full(k.size, 1e7), np.full(k.size, 5.0),
                                     (ref(k) - y(k)) * 1e6])}),
    }


def generate(path, seconds, storage='mcap'):
    """Write the benchmark bag; return (messages, seconds taken)."""
    from fiber_align.analysis import bag as bagio
    n = int(round(seconds * RATE_HZ))
    series = _series(n)
    t0 = time.perf_counter()
    bagio.write_bag(path, series, storage=storage, namespace='bench')
    return n * len(series), time.perf_counter() - t0


_CHILD = r'''
import sys, time, json
t0 = time.perf_counter()
from fiber_align.analysis.cli import analyze_bag
res, data = analyze_bag(sys.argv[1], None, (0.0, 100.0), keep_arrays=sys.argv[2] == '1')
if sys.argv[2] == '1':
    from fiber_align.analysis import plots
    plots.make_figures(sys.argv[3], data)
print(json.dumps({'s': time.perf_counter() - t0,
                  'steps': len(res['metrics']['loop'].get('steps', [])),
                  'notes': res['notes']}))
'''


def analyse(path, plots_dir=None):
    """Analyse ``path`` in a fresh subprocess; return (seconds, peak RSS in MB, child output)."""
    import json
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, '-c', _CHILD, str(path), '1' if plots_dir else '0',
                        str(plots_dir or '')], capture_output=True, text=True, timeout=3600)
    wall = time.perf_counter() - t0
    if p.returncode:
        raise RuntimeError(p.stderr)
    peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if peak_kb <= before:
        peak_kb = before   # an earlier, bigger child keeps the maximum: run one per process
    return wall, peak_kb / 1024.0, json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None):
    """Run the benchmark and print a Markdown table."""
    ap = argparse.ArgumentParser(prog='bench_analysis')
    ap.add_argument('--quick', action='store_true', help='60 s of data instead of one hour')
    ap.add_argument('--seconds', type=float, default=None, help='run length to generate (s)')
    ap.add_argument('--storage', default='mcap', choices=['mcap', 'sqlite3'])
    ap.add_argument('--keep', metavar='DIR', help='keep (or reuse) the bag in DIR')
    ap.add_argument('--plots', action='store_true', help='also time the figures')
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    seconds = args.seconds or (60.0 if args.quick else 3600.0)
    tmp = None
    if args.keep:
        bag = Path(args.keep)
    else:
        tmp = tempfile.mkdtemp(prefix='bench_analysis_')
        bag = Path(tmp) / 'bag'
    try:
        if bag.exists():
            gen_s, msgs = float('nan'), None
        else:
            msgs, gen_s = generate(bag, seconds, args.storage)
        if msgs is None:
            msgs = int(round(seconds * RATE_HZ)) * 8
        size_mb = sum(f.stat().st_size for f in bag.rglob('*') if f.is_file()) / 2**20
        wall, rss, child = analyse(bag, (Path(tmp or bag.parent) / 'plots')
                                   if args.plots else None)
        rate = msgs / wall
        print('| run | storage | messages | bag size | generate | analyse (wall) | '
              'messages/s | peak RSS | goal |')
        print('|---|---|---|---|---|---|---|---|---|')
        print('| %g s at %g Hz, 8 topics%s | %s | %d | %.0f MB | %.1f s | %.1f s | %.2f M | '
              '%.0f MB | <= 500 MB, > 1 M/s: %s |'
              % (seconds, RATE_HZ, ' + plots' if args.plots else '', args.storage, msgs,
                 size_mb, gen_s, wall, rate / 1e6, rss,
                 'met' if rss <= 500 and rate > 1e6 else 'NOT met'))
        print('\n(steps found: %d; analysis time inside the child: %.1f s)'
              % (child['steps'], child['s']))
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
