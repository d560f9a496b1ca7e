# SPDX-License-Identifier: Apache-2.0
"""
Realtime soak: new random setpoints for minutes, every one checked, memory watched.

Starts ``bringup --scenario none --sync realtime`` (the default composed graph) and an
outside rclpy client that publishes a new setpoint drawn uniformly from 10..80 um every
``--interval`` s (0.5), reads ``displacement`` and, ``--check-after`` s (0.3) after each
setpoint left it (its ``publish`` returned), takes the mean of the samples in the
following 20 ms as where the actuator is. Reported: how many setpoints were missed by more
than 1 um (median and worst miss), the driver's watchdog trips (``/diagnostics``), and
each process's resident memory after the first minute and at the end (MB; the goal: within
5 MB).

With ``--cli`` a user works beside it with the upstream ``ros2`` CLI: every ``--cli-period``
s (2) one round of ``ros2 node list``, ``param list``, ``param get`` and ``param set`` (the
current value again) of a live parameter of the next node in turn, ``topic echo --once
displacement`` and ``lifecycle get /actuator_driver``; the CLI's daemon is stopped at the
end. The driver's cycle figures (``cycle.*`` on ``/diagnostics``) are reported as the worst
window and the run's share of missed periods.

With ``--baseline`` the same soak first runs with the DDS publishes on the control thread
(``publish_thread: false``, the code before the publish thread), then as shipped: the two
columns of one run.

Usage: ``python -m bench.bench_soak [--minutes 10] [--interval 0.5] [--hogs 0] [--cli]
[--baseline] [--json FILE]``.
"""

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from fiber_align.analysis.run_summary import beyond_floor
from fiber_align.graph.description import build
from fiber_align.procstat import rss_bytes


def main(argv=None):
    """Run the soak; print the figures (and write JSON with ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--minutes', type=float, default=10.0)
    ap.add_argument('--interval', type=float, default=0.5)
    ap.add_argument('--check-after', type=float, default=0.3)
    ap.add_argument('--hogs', type=int, default=0)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--cli', action='store_true', help='run ros2 CLI commands beside it')
    ap.add_argument('--cli-period', type=float, default=2.0)
    ap.add_argument('--baseline', action='store_true',
                    help='first run with publish_thread false (DDS publishes on the '
                    'control thread)')
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    runs = {}
    if a.baseline:
        with tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False) as f:
            f.write('/**:\n  ros__parameters:\n    publish_thread: false\n')
        try:
            runs['publish_thread_false'] = soak(a, ['--params-file', f.name])
        finally:
            os.unlink(f.name)
    runs['shipped'] = soak(a, [])
    out = runs['shipped'] if len(runs) == 1 else runs
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump(out, f, indent=1)
    return 0


def soak(a, extra):
    """Return the figures of one soak, ``bringup`` started with the arguments ``extra``."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    log = tempfile.NamedTemporaryFile('w+', suffix='.log', delete=False)
    summary = log.name + '.summary.json'
    proc = subprocess.Popen([sys.executable, '-m', 'fiber_align.bringup', '--scenario',
                             'none', '--sync', 'realtime', '--quiet', '--summary', summary]
                            + list(extra),
                            stdout=log,
                            stderr=subprocess.STDOUT)
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(a.hogs)]
    rclpy.init()
    node = rclpy.create_node('soak_client')
    ys, trips = [], {'n': 0}

    def on_y(m):
        # the sample's own time (the plant's wall-clock stamp), not its arrival: outside
        # readers may get a sample late, and the check is about where the actuator was
        st = m.header.stamp
        ys.append((st.sec + 1e-9 * st.nanosec, m.position[0]))
        del ys[:-2000]

    cycles = []

    def on_diag(m):
        for st in m.status:
            if st.name.endswith('actuator_driver'):
                vals = {kv.key: kv.value for kv in st.values}
                if 'watchdog_count' in vals:
                    trips['n'] = max(trips['n'], int(float(vals['watchdog_count'])))
                if 'cycle.missed_share' in vals:
                    cycles.append(float(vals['cycle.missed_share']))
    node.create_subscription(JointState, 'displacement', on_y, 100)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    pub = node.create_publisher(Float64, 'setpoint', 10)
    rng = np.random.default_rng(a.seed)
    misses, rss, cli = [], {}, None
    publish_s, late = [], []    # the client's own publish time (s); the missed setpoints
    try:
        end = time.monotonic() + 60
        while 'graph up' not in open(log.name).read() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        pids = {m.group(1): int(m.group(2)) for m in re.finditer(
            r'started (\w+) \(pid (\d+)\)', open(log.name).read())}
        while pub.get_subscription_count() < 1 and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        cli = CliUser(node, a.cli_period) if a.cli else None
        t_start = time.monotonic()
        t_end = t_start + 60.0 * a.minutes
        while time.monotonic() < t_end:
            r = float(rng.uniform(10e-6, 80e-6))
            c0 = time.monotonic()
            pub.publish(Float64(data=r))
            publish_s.append(time.monotonic() - c0)
            # the check counts from when the setpoint left this client: its own publish
            # can wait in its participant's lock while ros2 commands join (reported as
            # client_publish_max_s), time the graph never had the setpoint for
            t0 = time.time()
            t_wait = time.monotonic() + a.check_after + 0.02
            t_win = t0 + a.check_after + 0.02
            while time.monotonic() < t_wait or (
                    ys and ys[-1][0] < t_win and time.monotonic() < t_wait + 2.0):
                rclpy.spin_once(node, timeout_sec=0.005)
            win = [y for t, y in ys if t0 + a.check_after <= t <= t0 + a.check_after + 0.02]
            misses.append(abs(np.mean(win) - r) if win else float('inf'))
            if misses[-1] > 1e-6:
                # the setpoint, when the client sent it, how long its own publish took,
                # and the samples it had around the check (for a miss's cause)
                late.append({'r_m': r, 'miss_m': misses[-1], 'publish_s': publish_s[-1],
                             'samples_seen': len(win), 'at_s': time.monotonic() - t_start})
            if 'minute1' not in rss and time.monotonic() - t_start >= 60.0:
                rss['minute1'] = {k: rss_bytes(p) / 1e6 for k, p in pids.items()}
            while time.time() < t0 + a.interval:
                rclpy.spin_once(node, timeout_sec=0.01)
        rss['end'] = {k: rss_bytes(p) / 1e6 for k, p in pids.items()}
    finally:
        if cli is not None:
            cli.stop()
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
    # no sample in the window: this client got none in time (its reads lag), not a miss
    unseen = int(np.sum(~np.isfinite(m)))
    m = m[np.isfinite(m)]
    bad = m[m > 1e-6]
    out = {'setpoints': int(m.size) + unseen, 'missed_by_more_than_1um': int(bad.size),
           'not_seen_by_the_client': unseen,
           'median_miss_um': float(np.median(bad) * 1e6) if bad.size else 0.0,
           'worst_miss_um': float(m.max() * 1e6) if m.size else None,
           'watchdog_trips': trips['n'], 'rss_mb': rss,
           'client_publish_max_s': max(publish_s) if publish_s else None,
           'missed': late[:20],
           'cycle_missed_share_windows': {
               'n': len(cycles), 'worst': max(cycles) if cycles else None,
               'median': float(np.median(cycles)) if cycles else None,
               'mean': float(np.mean(cycles)) if cycles else None},
           'cli_commands': cli.counts if cli is not None else None,
           'cli_failures': cli.failures[:20] if cli is not None else None,
           'minutes': a.minutes, 'hogs': a.hogs,
           'load_average': os.getloadavg()}
    out.update(graph_cycles(summary))
    growth = {k: rss['end'][k] - rss['minute1'][k] for k in rss.get('minute1', {})
              if k in rss.get('end', {})}
    out['rss_growth_after_minute1_mb'] = growth
    return out


def graph_cycles(path):
    """
    Return the run's missed cycles beside the machine's floor, from bringup's summary.

    ``missed_share`` (the plant's, the whole run), ``floor`` (the bare loop beside the
    graph: :mod:`fiber_align.control.floor_probe`), ``beyond_floor_share``, and the
    summary's ``goals_missed`` and ``machine_limits``; ``{}`` without a summary.
    """
    try:
        with open(path, encoding='utf-8') as f:
            s = json.load(f)
    except (OSError, ValueError):
        return {}
    ms = s.get('realtime', {}).get('missed_share')
    return {'missed_share': ms, 'floor': s.get('floor'),
            'beyond_floor_share': beyond_floor(ms, s.get('floor')),
            'goals_missed': s.get('goals_missed'), 'machine_limits': s.get('machine_limits')}


def ros2_env():
    """Return the environment of the upstream ``ros2`` CLI (``../shared/ros2-tools/env.sh``)."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env_sh = os.path.join(here, '..', 'shared', 'ros2-tools', 'env.sh')
    out = subprocess.run(['bash', '-c', '. "$0" "$1" >/dev/null && env -0', env_sh,
                          sys.prefix], capture_output=True, timeout=60, check=True)
    return dict(kv.split('=', 1) for kv in out.stdout.decode().split('\0') if '=' in kv)


class CliUser:
    """A user at the ``ros2`` CLI beside the graph: one round every ``period_s`` (s)."""

    def __init__(self, client, period_s):
        """Find each node's live parameters (through ``client``), start the thread."""
        import threading
        self.env = ros2_env() if shutil.which('ros2') is None else dict(os.environ)
        self.period_s = float(period_s)
        self.targets = live_parameters(client)
        self.counts = {'rounds': 0, 'commands': 0, 'failed': 0, 'timeouts': 0,
                       'live_parameters': len(self.targets)}
        self.failures = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _ros2(self, *args):
        self.counts['commands'] += 1
        try:
            p = subprocess.run(['ros2'] + list(args), env=self.env, capture_output=True,
                               text=True, timeout=30)
            if p.returncode != 0:
                self.counts['failed'] += 1
                self.failures.append('%s: %s' % (' '.join(args), (p.stderr or p.stdout)
                                                 .strip().splitlines()[-1:]))
            return p.stdout
        except subprocess.TimeoutExpired:
            self.counts['timeouts'] += 1
            self.failures.append('%s: timed out (30 s)' % ' '.join(args))
            return ''

    def _run(self):
        i = 0
        while not self._stop.is_set():
            t0 = time.monotonic()
            self._ros2('node', 'list')
            self._ros2('param', 'list')
            if self.targets:
                name, param, value = self.targets[i % len(self.targets)]
                self._ros2('param', 'get', name, param)
                self._ros2('param', 'set', name, param, value)
            self._ros2('topic', 'echo', '--once', 'displacement')
            self._ros2('lifecycle', 'get', '/actuator_driver')
            self.counts['rounds'] += 1
            i += 1
            self._stop.wait(max(0.0, t0 + self.period_s - time.monotonic()))

    def stop(self):
        """End the rounds and stop the CLI's daemon."""
        self._stop.set()
        self._thread.join(timeout=60)
        subprocess.run(['ros2', 'daemon', 'stop'], env=self.env, capture_output=True,
                       timeout=30)


def live_parameters(client, timeout_s=10.0):
    """
    Return ``(node, parameter, value text)`` of every settable scalar parameter of the graph.

    Asked through the parameter services of each node of the graph (its description's,
    waited for up to ``timeout_s`` s: a new client discovers them one announcement at a
    time); a parameter whose descriptor is read-only, or that is not a bool, int, float
    or string, is left out.
    """
    import rclpy
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters
    want = {n.rsplit('/', 1)[-1] for n in build(scenario='none').nodes}
    end = time.monotonic() + timeout_s
    while not want <= {n for n, _ in client.get_node_names_and_namespaces()} \
            and time.monotonic() < end:
        rclpy.spin_once(client, timeout_sec=0.1)
    out = []
    for name, ns in client.get_node_names_and_namespaces():
        if name.startswith('_') or name == client.get_name():
            continue
        fq = (ns.rstrip('/') + '/' + name)
        calls = {}
        for srv, typ in (('list_parameters', ListParameters),
                         ('describe_parameters', DescribeParameters),
                         ('get_parameters', GetParameters)):
            calls[srv] = client.create_client(typ, fq + '/' + srv)

        def call(srv, req):
            c = calls[srv]
            if not c.wait_for_service(timeout_sec=timeout_s):
                return None
            fut = c.call_async(req)
            rclpy.spin_until_future_complete(client, fut, timeout_sec=timeout_s)
            return fut.result()
        names = call('list_parameters', ListParameters.Request())
        if names is None:
            continue
        names = [n for n in names.result.names if n != 'use_sim_time']
        desc = call('describe_parameters', DescribeParameters.Request(names=names))
        vals = call('get_parameters', GetParameters.Request(names=names))
        for c in calls.values():
            client.destroy_client(c)
        if desc is None or vals is None:
            continue
        for n, d, v in zip(names, desc.descriptors, vals.values):
            if d.read_only:
                continue
            text = {ParameterType.PARAMETER_BOOL: lambda: str(v.bool_value).lower(),
                    ParameterType.PARAMETER_INTEGER: lambda: str(v.integer_value),
                    ParameterType.PARAMETER_DOUBLE: lambda: repr(v.double_value),
                    ParameterType.PARAMETER_STRING: lambda: v.string_value or "''",
                    }.get(v.type)
            if text is not None:
                out.append((fq, n, text()))
                break                   # one live parameter per node
    return out


if __name__ == '__main__':
    sys.exit(main())
