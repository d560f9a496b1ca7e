# SPDX-License-Identifier: Apache-2.0
"""
Realtime soak: new random setpoints for minutes, every one checked, memory watched.

Starts ``bringup --scenario none --sync realtime`` (the default composed graph) and an
outside rclpy client that publishes a new setpoint drawn uniformly from 10..80 um every
``--interval`` s (0.5), reads ``displacement`` and, ``--check-after`` s (0.3) after
each setpoint, takes the mean of the samples in the following 20 ms as where the
actuator is. Reported: how many setpoints were missed by more than 1 um (median and worst
miss), the driver's watchdog trips (``/diagnostics``), and each process's resident
memory after the first minute and at the end (MB; the goal: within 5 MB).

Usage: ``python -m bench.bench_soak [--minutes 10] [--hogs 0] [--json FILE]``.
"""

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from fiber_align.nodes.bringup.children import rss_bytes


def main(argv=None):
    """Run the soak; print the figures (and write JSON with ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--minutes', type=float, default=10.0)
    ap.add_argument('--interval', type=float, default=0.5)
    ap.add_argument('--check-after', type=float, default=0.3)
    ap.add_argument('--hogs', type=int, default=0)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    log = tempfile.NamedTemporaryFile('w+', suffix='.log', delete=False)
    proc = subprocess.Popen([sys.executable, '-m', 'fiber_align.nodes.bringup', '--scenario',
                             'none', '--sync', 'realtime', '--quiet'], stdout=log,
                            stderr=subprocess.STDOUT)
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(a.hogs)]
    rclpy.init()
    node = rclpy.create_node('soak_client')
    ys, trips = [], {'n': 0}

    def on_y(m):
        ys.append((time.monotonic(), m.position[0]))
        del ys[:-2000]

    def on_diag(m):
        for st in m.status:
            if st.name.endswith('actuator_driver'):
                for kv in st.values:
                    if kv.key == 'watchdog_count':
                        trips['n'] = max(trips['n'], int(float(kv.value)))
    node.create_subscription(JointState, 'displacement', on_y, 100)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    pub = node.create_publisher(Float64, 'setpoint', 10)
    rng = np.random.default_rng(a.seed)
    misses, rss = [], {}
    try:
        end = time.monotonic() + 60
        while 'graph up' not in open(log.name).read() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        pids = {m.group(1): int(m.group(2)) for m in re.finditer(
            r'started (\w+) \(pid (\d+)\)', open(log.name).read())}
        while pub.get_subscription_count() < 1 and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        t_start = time.monotonic()
        t_end = t_start + 60.0 * a.minutes
        while time.monotonic() < t_end:
            r = float(rng.uniform(10e-6, 80e-6))
            t0 = time.monotonic()
            pub.publish(Float64(data=r))
            while time.monotonic() < t0 + a.check_after + 0.02:
                rclpy.spin_once(node, timeout_sec=0.005)
            win = [y for t, y in ys if t0 + a.check_after <= t <= t0 + a.check_after + 0.02]
            misses.append(abs(np.mean(win) - r) if win else float('inf'))
            if 'minute1' not in rss and time.monotonic() - t_start >= 60.0:
                rss['minute1'] = {k: rss_bytes(p) / 1e6 for k, p in pids.items()}
            while time.monotonic() < t0 + a.interval:
                rclpy.spin_once(node, timeout_sec=0.01)
        rss['end'] = {k: rss_bytes(p) / 1e6 for k, p in pids.items()}
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
        for h in hogs:
            h.kill()
            h.wait()
    m = np.array(misses)
    bad = m[m > 1e-6]
    out = {'setpoints': int(m.size), 'missed_by_more_than_1um': int(bad.size),
           'median_miss_um': float(np.median(bad) * 1e6) if bad.size else 0.0,
           'worst_miss_um': float(m.max() * 1e6) if m.size else None,
           'watchdog_trips': trips['n'], 'rss_mb': rss, 'minutes': a.minutes, 'hogs': a.hogs,
           'load_average': os.getloadavg()}
    growth = {k: rss['end'][k] - rss['minute1'][k] for k in rss.get('minute1', {})
              if k in rss.get('end', {})}
    out['rss_growth_after_minute1_mb'] = growth
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
