# SPDX-License-Identifier: Apache-2.0
"""
One graph per set of names (issue 39.1), with ``ros2 launch`` as a user starts it.

Two launches of one graph in one ``ROS_DOMAIN_ID`` (two rig PCs of one lab on domain 0):
the second exits non-zero within 10 s with one line and starts no process, while the
first holds its 60 um setpoint within 1 um; two launched at the same moment, before
either graph's nodes exist: the later is refused the same way. A foreign node publishing
100 V on a drive topic (``feedforward_voltage``) at 1 kHz for 5 s beside the 1-D graph,
the rig and the station: the driver holds its output, an ERROR on ``/diagnostics`` names
the node, the displacement never leaves the setpoint range, and after the node is gone
an ``~/enable true`` re-arms the driver. Every wait is bounded; every launch is stopped by
its pid and group, also on failure.
"""

import subprocess
import sys
import threading
import time

import pytest

from fiber_align.graph.arguments import describe
from procs import level, wait_log
from test_ros2_cli import descendants, ros2_env, spawn, stop_launch  # noqa: F401

pytestmark = [pytest.mark.ros, pytest.mark.slow]

LAUNCH = ['ros2', 'launch', 'fiber_align', 'fiber_align.launch.py']
BRINGUP = [sys.executable, '-m', 'fiber_align.bringup', '--quiet']
#: the foreign node's name (the ERROR must name it)
INTRUDER = 'intruder_graph_b'


class Client:
    """An rclpy client on its own thread: displacement, drive and /diagnostics of an axis."""

    def __init__(self, axis):
        """Subscribe to ``<axis>/displacement``, ``<axis>/drive_voltage``, /diagnostics."""
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64

        from fiber_align.nodes.ros import qos
        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('one_owner_client', context=self.ctx)
        self.ys, self.drives, self.diags, self.lock = [], [], [], threading.Lock()
        p = axis + '/' if axis else '/'
        self.node.create_subscription(JointState, p + 'displacement', lambda m: self._add(
            self.ys, m.position[0]), qos.LIVE_QOS)
        self.node.create_subscription(Float64, p + 'drive_voltage', lambda m: self._add(
            self.drives, m.data), qos.LIVE_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: [
            self._add(self.diags, (level(s), s.name, s.message)) for s in m.status],
            qos.DIAG_QOS)
        self.setpoint = self.node.create_publisher(Float64, p + 'setpoint', qos.SETPOINT_QOS)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self.ex.spin, daemon=True)
        self.thread.start()

    def _add(self, where, value):
        with self.lock:
            where.append((time.monotonic(), value))

    def since(self, where, t0, t1=None):
        """Return the values of ``where`` received in [t0, t1]."""
        with self.lock:
            return [v for t, v in where if t >= t0 and (t1 is None or t <= t1)]

    def wait(self, cond, bound_s):
        """Wait (bounded, s) until ``cond()``; return it."""
        end = time.monotonic() + bound_s
        while not cond() and time.monotonic() < end:
            time.sleep(0.05)
        return cond()

    def hold_at(self, y_m, bound_s=20.0):
        """Publish the setpoint ``y_m`` (m) once matched; wait until within 1 um of it."""
        from std_msgs.msg import Float64
        assert self.wait(lambda: self.setpoint.get_subscription_count() >= 1, bound_s)
        self.setpoint.publish(Float64(data=float(y_m)))
        t0 = time.monotonic()
        return self.wait(lambda: len(self.since(self.ys, t0)) > 200 and all(
            abs(y - y_m) < 1e-6 for y in self.since(self.ys, time.monotonic() - 0.5)),
            bound_s)

    def close(self):
        """Stop the executor, destroy the node, shut the context down."""
        self.ex.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()
        self.thread.join(5.0)


def intrude(client, topic, volts, seconds, rate_hz=1000.0):
    """Publish ``volts`` on ``topic`` at ``rate_hz`` for ``seconds`` from a foreign node."""
    import rclpy
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros import qos
    node = rclpy.create_node(INTRUDER, context=client.ctx)
    pub = node.create_publisher(Float64, topic, qos.LIVE_QOS)
    t0, k = time.monotonic(), 0
    try:
        while time.monotonic() - t0 < seconds:
            pub.publish(Float64(data=float(volts)))
            k += 1
            time.sleep(max(0.0, t0 + k / rate_hz - time.monotonic()))
    finally:
        node.destroy_node()
    return k


def _names_its_nodes(line, args):
    """
    Return True if ``line`` names a node of the graph of launch ``args``.

    Discovery may show any of the running graph's nodes first; the refusal names those
    it found.
    """
    g = describe(args)
    ns = '/%s' % g.namespace if g.namespace else ''
    return any('%s/%s ' % (ns, n) in line or '%s/%s,' % (ns, n) in line for n in g.nodes)


def test_a_second_launch_of_the_same_graph_is_refused_and_the_first_holds(
        ros2_env, tmp_path):  # noqa: F811
    log1, log2 = tmp_path / 'first.log', tmp_path / 'second.log'
    first = spawn(ros2_env, LAUNCH, log1)
    second = client = None
    try:
        assert wait_log(log1, 'startup done', 60.0, first), log1.read_text()[-3000:]
        client = Client('')
        assert client.hold_at(60e-6), client.since(client.ys, 0.0)[-5:]
        t0 = time.monotonic()
        second = spawn(ros2_env, LAUNCH, log2)
        rc = second.wait(timeout=10.0)
        took = time.monotonic() - t0
        time.sleep(3.0)                   # the first graph goes on after the refusal
        ys = client.since(client.ys, t0)
        text = log2.read_text(errors='replace')
        lines = [ln for ln in text.splitlines() if 'another graph owns' in ln]
        print('second launch: exit %d after %.2f s: %s' % (rc, took, lines))
        print('first graph over %.1f s: %d samples, %.3f..%.3f um' % (
            time.monotonic() - t0, len(ys), min(ys) * 1e6, max(ys) * 1e6))
        assert rc != 0 and took < 10.0, text
        assert len(lines) == 1 and _names_its_nodes(lines[0], {}), text
        assert 'process started' not in text and 'Traceback' not in text, text
        assert not descendants(second.pid)
        assert len(ys) > 1000 and all(abs(y - 60e-6) <= 1e-6 for y in ys), \
            (min(ys), max(ys))
    finally:
        client and client.close()
        second and stop_launch(second)
        stop_launch(first)


def test_two_launches_of_one_graph_at_the_same_moment_one_is_refused(
        ros2_env, tmp_path):  # noqa: F811
    """
    Neither graph's nodes exist when both probes look: the starts' markers order them.

    The later start exits non-zero within 10 s with one line; the earlier one starts.
    """
    logs = [tmp_path / 'a.log', tmp_path / 'b.log']
    launches = []
    try:
        t0 = time.monotonic()
        launches = [spawn(ros2_env, LAUNCH, log) for log in logs]
        end = t0 + 10.0
        while time.monotonic() < end and all(p.poll() is None for p in launches):
            time.sleep(0.05)
        took = time.monotonic() - t0
        codes = [p.poll() for p in launches]
        texts = [log.read_text(errors='replace') for log in logs]
        print('two launches at once: exit codes %s after %.2f s' % (codes, took))
        refused = [i for i, c in enumerate(codes) if c is not None]
        assert len(refused) == 1 and codes[refused[0]] != 0, (codes, texts)
        lines = [ln for ln in texts[refused[0]].splitlines() if 'another graph of these '
                 'names started' in ln]
        print(lines)
        assert len(lines) == 1 and 'process started' not in texts[refused[0]], texts
        kept = launches[1 - refused[0]]
        assert wait_log(logs[1 - refused[0]], 'startup done', 60.0, kept), texts
    finally:
        for p in launches:
            stop_launch(p)


@pytest.mark.parametrize('first, second', [
    (LAUNCH, BRINGUP + ['--scenario', 'none', '--sync', 'realtime', '--duration', '60']),
    (LAUNCH + ['rig:=true'], BRINGUP + ['--rig'])], ids=['1-D', 'rig'])
def test_bringup_beside_a_running_graph_of_its_names_is_refused(
        ros2_env, tmp_path, first, second):  # noqa: F811
    log = tmp_path / 'first.log'
    proc = spawn(ros2_env, first, log)
    try:
        assert wait_log(log, 'startup done', 60.0, proc), log.read_text()[-3000:]
        t0 = time.monotonic()
        out = subprocess.run(second, env=ros2_env, capture_output=True, text=True,
                             timeout=30.0)
        took = time.monotonic() - t0
        text = out.stdout + out.stderr
        print('bringup: exit %d after %.2f s: %s' % (out.returncode, took, text.strip()))
        assert out.returncode != 0 and took < 10.0, text
        lines = text.strip().splitlines()            # one line, no process started
        assert len(lines) == 1 and 'another graph owns' in lines[0], text
        assert _names_its_nodes(lines[0], {'rig': 'true'} if '--rig' in second else {})
    finally:
        stop_launch(proc)


#: s: the drives of the last ticks before the hold may arrive this long after the ERROR.
#: The client stamps them on arrival, and its executor (1 kHz of drives and positions)
#: fell 1.4-3.2 s behind on 2026-12-06 in the multi-process 1-D graph, in this tree and
#: in the one before (097888d) alike: the lag is the client's; the displacement's range,
#: checked on every sample, is the safety property
HELD_LAG_S = 4.0
#: s: the held run lasts at least this long before the intruder is gone (it sends 5 s)
HELD_MIN_S = 0.5


@pytest.mark.parametrize('args, axis', [
    ([], ''), (['composed:=false'], ''), (['rig:=true'], '/rig/x'),
    (['station:=true'], '/station/in/x')],
    ids=['1-D', '1-D-processes', 'rig', 'station'])
def test_a_foreign_drive_publisher_holds_the_driver_until_gone_and_rearmed(
        ros2_env, tmp_path, args, axis):  # noqa: F811
    from std_srvs.srv import SetBool
    g = describe(dict(a.split(':=') for a in args))
    comp_name = (axis.split('/', 2)[-1] + '/' if axis else '') + 'hysteresis_compensator'
    comp = g.node_params(comp_name)
    # the range, widened by 6 sigma of the sensor's noise (the fiber at rest at 0 um
    # reads a few tens of nm below it)
    noise = 6.0 * g.node_params(comp_name.replace('hysteresis_compensator',
                                                  'simulated_actuator'))['noise_rms_m']
    lo, hi = comp['setpoint_min_m'] - noise, comp['setpoint_max_m'] + noise
    log = tmp_path / 'launch.log'
    proc = spawn(ros2_env, LAUNCH + args, log)
    client = None
    try:
        assert wait_log(log, 'startup done', 60.0, proc), log.read_text()[-3000:]
        client = Client(axis)
        if not axis:
            assert client.hold_at(60e-6)
        assert client.wait(lambda: len(client.ys) > 500, 20.0)
        t0 = time.monotonic()
        sent = intrude(client, axis + '/feedforward_voltage', 100.0, 5.0)
        t1 = time.monotonic()
        time.sleep(1.0)
        with client.lock:
            errors = [(t, lv, name, m) for t, (lv, name, m) in client.diags
                      if t >= t0 and lv == 2 and INTRUDER in m]
        assert errors, client.since(client.diags, t0)[-5:]
        t_err = errors[0][0]
        # held from the ERROR on (a report's own delay aside) until the node is gone
        ys = client.since(client.ys, t0)
        # the drives are stamped on arrival: a loaded executor takes a few of the last
        # ones before the hold after the ERROR; the held run is the constant tail, which
        # must begin within HELD_LAG_S of the ERROR and last until the intruder is gone
        with client.lock:
            timed = [(t, v) for t, v in client.drives if t_err <= t <= t1]
        k = len(timed)
        while k > 0 and timed[k - 1][1] == timed[-1][1]:
            k -= 1
        t_held = timed[k][0] if timed else float('inf')
        drives = [v for _, v in timed[k:]]
        print('%s: %d foreign messages; ERROR after %.2f s; displacement %.3f..%.3f um '
              '(range %.1f..%.1f); drives while held %s; ERROR: %s' % (
                  axis or '1-D', sent, t_err - t0, min(ys) * 1e6, max(ys) * 1e6, lo * 1e6,
                  hi * 1e6, sorted(set(drives))[:4], errors[0][1:]))
        # 1 kHz asked for 5 s; a loaded machine gives less (853 once, in a clean clone's
        # suite): still a publisher the driver must catch
        assert sent > 500
        assert t_err - t0 < 2.0
        assert 'actuator_driver' in errors[0][2] or 'mdt693b' in errors[0][2]
        assert all(lo <= y <= hi for y in ys), (min(ys), max(ys))
        print('held from %.3f s after the ERROR (arrival), %d drives' % (
            t_held - t_err, len(drives)))
        assert t_held - t_err < HELD_LAG_S and t1 - t_held > HELD_MIN_S, sorted(set(
            v for _, v in timed))[:10]
        assert 100.0 not in drives
        # gone: still held until re-armed; ~/enable true re-arms
        driver = '%s/actuator_driver' % axis
        cli = client.node.create_client(SetBool, driver + '/enable')
        assert cli.wait_for_service(timeout_sec=10.0)
        fut = cli.call_async(SetBool.Request(data=True))
        assert client.wait(fut.done, 10.0) and fut.result().success
        t2 = time.monotonic()
        assert client.wait(lambda: any(
            lv == 0 and name == driver for lv, name, _ in client.since(client.diags, t2)),
            10.0), client.since(client.diags, t2)[-5:]
        if not axis:                    # it follows the setpoints again
            assert client.hold_at(40e-6)
    finally:
        client and client.close()
        stop_launch(proc)
