# SPDX-License-Identifier: Apache-2.0
"""
Benchmark the flight recorder: the recorder's CPU and memory in three modes, one run.

One realtime 1-D run (``bringup --scenario sine --sync realtime``, 1 kHz, composed,
no recorder of its own) with three recorder processes of the same executable beside it,
reading the same topics through DDS: ``full_only`` (the full recording, as the graph's
own recorder in a multi-process graph), ``flight_full`` (full recording and snapshots)
and ``flight_only`` (``record`` false, snapshots only). Halfway, each flight recorder
is asked for one snapshot (``~/snapshot``), so its write is in the
figures. Every second: each recorder's CPU (s/s, ``/proc/<pid>/stat`` utime + stime)
and RSS (MB, ``VmRSS``); the medians over the steady part (from ``--skip`` s) and the
largest RSS, the ratios to the full recorder's.

Usage (starts ROS processes: under the shared lock): ``flock /tmp/fiber_align_ros.lock
python -m bench.bench_flight [--duration 30] [--skip 12]``.
"""

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from fiber_align.procstat import cpu_time_s, rss_bytes

MODES = ('full_only', 'flight_full', 'flight_only')


def _snapshot(name):
    """Call ``/<name>/snapshot`` once with the ros2 CLI-free rclpy client (bounded)."""
    import rclpy
    from std_srvs.srv import Trigger
    rclpy.init()
    try:
        node = rclpy.create_node('bench_flight_client')
        cli = node.create_client(Trigger, '/%s/snapshot' % name)
        if not cli.wait_for_service(timeout_sec=10.0):
            return 'no service'
        fut = cli.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, fut, timeout_sec=10.0)
        return fut.result().message if fut.done() else 'no answer'
    finally:
        rclpy.shutdown()


def main(argv=None):
    """Run the graph and the two flight recorders; print the figures (see the module)."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--duration', type=float, default=30.0, help='run length (s)')
    ap.add_argument('--skip', type=float, default=12.0,
                    help='s left out at the start (discovery; the rings filling)')
    a = ap.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix='bench_flight_')
    exe = [sys.executable, '-m', 'fiber_align.nodes.bag_recorder', '--ros-args']
    extra = {
        'full_only': exe + ['-r', '__node:=full_only', '-p', 'output:=%s/bag' % tmp],
        'flight_full': exe + ['-r', '__node:=flight_full', '-p', 'output:=%s/full' % tmp,
                              '-p', 'snapshots:=%s/snaps_full' % tmp],
        'flight_only': exe + ['-r', '__node:=flight_only', '-p', 'record:=false',
                              '-p', 'snapshots:=%s/snaps_only' % tmp],
    }
    log = open(os.path.join(tmp, 'bringup.log'), 'wb')
    graph = subprocess.Popen([sys.executable, '-m', 'fiber_align.bringup', '--scenario', 'sine',
                              '--sync', 'realtime', '--duration', str(a.duration),
                              '--catalog', 'none', '--quiet'], stdout=log,
                             stderr=subprocess.STDOUT, start_new_session=True)
    # the recorders once the graph is up: four processes starting at once on two cores
    # held the driver's lifecycle service past bringup's 5 s (2026-12-06)
    end = time.monotonic() + 60.0
    while graph.poll() is None and time.monotonic() < end and b'graph up' not in open(
            os.path.join(tmp, 'bringup.log'), 'rb').read():
        time.sleep(0.2)
    procs = {n: subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                 start_new_session=True) for n, cmd in extra.items()}
    pids = {n: p.pid for n, p in procs.items()}
    samples = {n: [] for n in MODES}
    t0, asked, prev = time.monotonic(), False, {}
    try:
        while graph.poll() is None and time.monotonic() - t0 < a.duration + 60:
            now = time.monotonic()
            for n, pid in pids.items():
                c, r = cpu_time_s(pid), rss_bytes(pid) / 2 ** 20
                if math.isnan(c):           # gone
                    continue
                if n in prev:
                    dt = now - prev[n][0]
                    samples[n].append((now - t0, (c - prev[n][1]) / dt, r))
                prev[n] = (now, c)
            if not asked and now - t0 > a.skip + 0.4 * (a.duration - a.skip):
                asked = True
                for n in ('flight_full', 'flight_only'):
                    print('%s: snapshot %s' % (n, _snapshot(n)))
            time.sleep(1.0)
    finally:
        for p in list(procs.values()) + [graph]:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in list(procs.values()) + [graph]:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()
    rows = {}
    for n in MODES:
        s = np.array([x for x in samples[n] if x[0] >= a.skip and x[0] <= a.duration]
                     ) if samples[n] else np.zeros((0, 3))
        rows[n] = (float(np.median(s[:, 1])) if len(s) else float('nan'),
                   float(np.median(s[:, 2])) if len(s) else float('nan'),
                   float(np.max(s[:, 2])) if len(s) else float('nan'), len(s))
    base = rows['full_only']
    print('recorder       mode                 CPU s/s (median)  RSS MB (median, max)  '
          'CPU / full  RSS / full  samples')
    for n, what in zip(MODES, ('full recording', 'full + snapshots', 'snapshots only')):
        cpu, rss, top, k = rows[n]
        print('%-14s %-20s %16.3f  %9.1f %9.1f  %10.2f  %10.2f  %7d' % (
            n, what, cpu, rss, top, cpu / base[0], rss / base[1], k))
    print('files in %s' % tmp)
    return 0


if __name__ == '__main__':
    sys.exit(main())
