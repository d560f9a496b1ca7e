# SPDX-License-Identifier: Apache-2.0
"""
Realtime graph as separate processes, driven by an outside rclpy client.

One graph (plant, compensator, controller, driver: one process each, realtime at 1 kHz)
serves the tests of this module, in file order: the client publishes one 50 um
setpoint and the actuator settles there; NaN, infinite and out-of-range setpoints are
rejected with a reason and a diagnostics WARN while the actuator stays; a controller
gain is set live in range (accepted, in effect) and out of range (rejected with the
reason); a compensator stopped for 0.3 s trips the driver's watchdog and the loop
resumes without a wind-up bump; the compensator, the controller or the driver
stalled 20 ms mid-move does not make the drive jump; killing the controller makes the
driver's watchdog
ramp the drive to 0 V and report ERROR, and a restarted controller brings the actuator
back to the setpoint without a re-send (the latched ``reference``), never beyond the
setpoint range by more than 2 um; a plant stalled 0.3 s replays the driver's ramp to
0 V instead of stepping to it; and a driver whose thread stalls 30 ms at a time during
that ramp still ramps (2 V a step), never steps the bimorph below -2 um.
"""

import contextlib
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest

import procs

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODES = ('simulated_actuator', 'hysteresis_compensator', 'fuzzy_pid_controller',
         'actuator_driver')
TARGET_M = 50e-6
TOL_M = 0.5e-6
OK, WARN, ERROR = b'\x00', b'\x01', b'\x02'
#: s: a service request unanswered this long is sent again (``Client.call``).
RESEND_S = 2.0


def spawn(name, log_dir, ros_args=()):
    """Start one node process (realtime, defaults from config/); log to a file."""
    log = open(Path(log_dir) / ('%s.log' % name), 'ab')
    extra = ['--ros-args'] + list(ros_args) if ros_args else []
    try:
        return subprocess.Popen([sys.executable, '-m', 'fiber_align.nodes.' + name] + extra,
                                env=dict(os.environ), stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    finally:
        log.close()


def stop(proc):
    """SIGINT, then SIGKILL after 5 s."""
    procs.stop(proc, grace_s=5.0)


class Client:
    """The outside client: publishes ``setpoint`` only, records what the graph shows."""

    def __init__(self):
        """Create the node, its subscriptions and the setpoint publisher."""
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64, Float64MultiArray

        from fiber_align.nodes.ros.qos import LATCHED_QOS
        self.rclpy = rclpy
        self.Float64 = Float64
        self.node = rclpy.create_node('outside_client')
        self.ys = []            # (receive time s, position m)
        self.stamped = []       # (the plant's sample stamp s, system clock; position m)
        self.drives = []        # (receive time s, V)
        self.diags = []         # (receive time s, node name, level byte, message)
        self.values = {}        # node name -> latest diagnostics key/values
        self.held = []          # (receive time s, drive_held)
        self.state = []         # controller_state data lists
        self.node.create_subscription(JointState, 'displacement', self._on_y, 100)
        self.node.create_subscription(Float64, 'drive_voltage', self._on_v, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)
        self.node.create_subscription(Float64MultiArray, 'controller_state',
                                      lambda m: self.state.append(list(m.data)), 100)
        self.node.create_subscription(Bool, 'drive_held', lambda m: self.held.append(
            (time.monotonic(), m.data)), LATCHED_QOS)
        self.pub = self.node.create_publisher(Float64, 'setpoint', 10)
        try:        # rclpy's C++ executor keeps up with the 1 kHz streams far better
            from rclpy.experimental import EventsExecutor
            self.executor = EventsExecutor()
        except ImportError:
            from rclpy.executors import SingleThreadedExecutor
            self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def close(self):
        """Destroy the executor and the node."""
        self.executor.remove_node(self.node)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()

    def _on_y(self, msg):
        self.ys.append((time.monotonic(), msg.position[0]))
        self.stamped.append((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                             msg.position[0]))

    def _on_v(self, msg):
        self.drives.append((time.monotonic(), msg.data))

    def _on_diag(self, msg):
        now = time.monotonic()
        for s in msg.status:
            self.diags.append((now, s.name.lstrip('/'), s.level, s.message))
            self.values[s.name.lstrip('/')] = {kv.key: kv.value for kv in s.values}

    def spin_for(self, seconds, until=None):
        """Spin up to ``seconds`` (s); return True as soon as ``until()`` holds."""
        if until is None:
            procs.spin_until(self.executor, lambda: False, seconds)
            return True
        return procs.spin_until(self.executor, until, seconds)

    def call(self, client, request, timeout=10.0, resend_s=RESEND_S):
        """
        Call a service with a bounded wait; return the response.

        The request is sent again every ``resend_s`` (s) without an answer (every call
        here is idempotent): a server drops its response when its discovery of this
        client's new response reader is not done within rmw_fastrtps's 100 ms, which a
        busy machine's SCHED_FIFO graph can make it miss.
        """
        assert client.wait_for_service(timeout_sec=timeout), client.srv_name
        end = time.monotonic() + timeout
        futs = []
        while time.monotonic() < end and not any(f.done() for f in futs):
            futs.append(client.call_async(request))
            self.spin_for(min(resend_s, max(0.0, end - time.monotonic())),
                          lambda: any(f.done() for f in futs))
        done = [f for f in futs if f.done()]
        for f in futs:
            if not f.done():
                client.remove_pending_request(f)
        assert done, 'no answer from %s within %g s (%d requests)' % (
            client.srv_name, timeout, len(futs))
        return done[0].result()

    def matched(self):
        """Return True when every control topic has all its endpoints (this client too)."""
        n = self.node
        return (self.pub.get_subscription_count() >= 1                  # the compensator
                and n.count_subscribers('/displacement') >= 3           # + this client
                and n.count_subscribers('/feedforward_voltage') >= 1    # driver
                and n.count_subscribers('/feedback_voltage') >= 1       # driver
                and n.count_publishers('/drive_voltage') >= 1
                and n.count_subscribers('/drive_voltage') >= 2)         # plant + client

    def publish(self, value):
        """Publish one setpoint (m)."""
        self.pub.publish(self.Float64(data=float(value)))

    def explain(self, t0, log_dir):
        """Return what the graph showed since ``t0`` (monotonic s), for a failed assert."""
        return ('y %s; drive %s; held %s; statuses since %s; values %s; logs %s' % (
            self.ys_since(t0)[-3:], self.drives[-3:], self.held[-3:],
            [(round(t - t0, 3), n, lv, m) for t, n, lv, m in self.diags
             if t > t0 and lv != OK][-8:],
            {n: v for n, v in self.values.items() if 'pid' in n or 'driver' in n}, log_dir))

    def around(self, t_mid, before=0.06, after=0.06, log_dir=None):
        """
        Return what the client saw from ``t_mid - before`` to ``t_mid + after`` (s).

        Positions (um) and drives (V) as ``(ms from t_mid, value)``; with ``log_dir`` also
        the last lines of each node's log: what a failed bound on a peak needs.
        """
        def near(seq):
            return [(round(1e3 * (t - t_mid), 1), round(v, 2)) for t, v in seq
                    if t_mid - before <= t <= t_mid + after]
        out = ['y (um) %s' % near([(t, 1e6 * y) for t, y in self.ys]),
               'drive (V) %s' % near(self.drives),
               'held %s' % [(round(1e3 * (t - t_mid), 1), h) for t, h in self.held],
               'statuses %s' % [(round(1e3 * (t - t_mid), 1), n, lv, m)
                                for t, n, lv, m in self.diags
                                if abs(t - t_mid) < 3.0 and lv != OK]]
        for f in sorted(Path(log_dir).glob('*.log')) if log_dir else ():
            out.append('%s:\n  %s' % (f.name, '\n  '.join(
                f.read_text(errors='replace').splitlines()[-12:])))
        return '\n'.join(out)

    def rearm_and_settle(self):
        """
        ``actuator_driver/enable`` true, the target setpoint, then wait until settled.

        The enable clears the trip history, so the earlier tests' trips do not latch
        the next one (3 within 10 s); the setpoint makes a test run alone (``-k``) start
        where it would after the others.
        """
        from std_srvs.srv import SetBool
        res = self.call(self.node.create_client(SetBool, 'actuator_driver/enable'),
                        SetBool.Request(data=True))
        assert res.success, res.message
        self.publish(TARGET_M)
        assert self.spin_for(5.0, lambda: self.settled(time.monotonic() - 0.3)), \
            self.ys_since(0.0)[-5:]

    def ys_since(self, t0):
        """Return the positions (m) received after ``t0`` (monotonic s)."""
        return [y for t, y in self.ys if t > t0]

    def trips_since(self, t0):
        """Return the receive times (s) of the driver's trips (ERROR, drive_held) after ``t0``."""
        self.spin_for(0.3)      # let late reports of a trip arrive
        return sorted([t for t, n, lv, m in self.diags
                       if t > t0 and n.endswith('actuator_driver') and lv == ERROR]
                      + [t for t, h in self.held if t > t0 and h])

    def steady_share(self, since, before_s=0.3, after_s=2.0):
        """
        Return the share of the samples after ``since`` within TOL_M, and the trips.

        A trip (a stalled node on this loaded machine) holds the drive or ramps it to the
        safe voltage: the samples from ``before_s`` before its report (the report comes
        after the drive was held) to ``after_s`` after it (the 2 s a setpoint settles in,
        :func:`test_outside_client_setpoint_settles`) are the trip's, not counted. The
        share is ``None`` when every sample is a trip's.
        """
        trips = self.trips_since(since)
        ys = [y for t, y in self.ys if t > since
              and not any(tt - before_s <= t <= tt + after_s for tt in trips)]
        share = sum(abs(y - TARGET_M) < TOL_M for y in ys) / len(ys) if ys else None
        return share, trips

    def check_steady(self, since, least=0.5):
        """
        Assert the loop stayed at the target after ``since``: no limit cycle.

        At least ``least`` of the samples no trip explains are within TOL_M (100 % when the
        machine is quiet; a node stalled short of a trip disturbs some), and after a trip
        the loop settles again.
        """
        share, trips = self.steady_share(since)
        print('steady: %s of the samples within 0.5 um, %d trip report(s)'
              % ('-' if share is None else '%.1f %%' % (100 * share), len(trips)))
        assert share is not None or trips
        if share is not None:
            assert share >= least, (share, trips)
        if trips:
            assert self.spin_for(5.0, lambda: self.settled(trips[-1])), (
                'not settled again after the trip at %.3f s' % trips[-1])

    def settled(self, since, n=100, least=20):
        """
        Return True when the last ``n`` samples after ``since`` are within TOL_M.

        At least ``least`` of them: this client shares the machine with four SCHED_FIFO
        node processes and may read only a part of the 1 kHz samples of a window.
        """
        tail = self.ys_since(since)[-n:]
        return len(tail) >= least and all(abs(y - TARGET_M) < TOL_M for y in tail)


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    """Start the four node processes and the client; activate the driver."""
    with running_graph(tmp_path_factory.mktemp('realtime_logs')) as g:
        yield g


@contextlib.contextmanager
def running_graph(log_dir, ros_args=None):
    """
    Start the four node processes and the client, activate the driver; yield them.

    :param ros_args: node name -> extra ``--ros-args`` arguments of that process.
    :yields: ``(client, {name: process}, log_dir)``; everything is stopped after.
    """
    import rclpy
    from lifecycle_msgs.srv import ChangeState
    procs = {n: spawn(n, log_dir, (ros_args or {}).get(n, ())) for n in NODES}
    rclpy.init()
    cl = None
    try:
        cl = Client()
        cli = cl.node.create_client(ChangeState, 'actuator_driver/change_state')
        for tid in (1, 3):      # configure, activate
            req = ChangeState.Request()
            req.transition.id = tid
            # sent once: a transition repeated is refused (it is not idempotent)
            assert cl.call(cli, req, timeout=30, resend_s=30).success
        assert cl.spin_for(30, lambda: cl.matched() and len(cl.drives) > 100), \
            'graph not running: see %s' % log_dir
        yield cl, procs, log_dir
    finally:
        if cl is not None:
            cl.close()
        rclpy.try_shutdown()
        for p in procs.values():
            stop(p)


def test_outside_client_setpoint_settles(graph):
    """
    One 50 um setpoint: the actuator settles within 0.5 um, well within 2 s.

    The settling time is the loop's, from the plant's sample stamps (system clock, as the
    publish time): the last sample outside the band, after the setpoint. This client's
    receive times are not: it reads four streams beside four SCHED_FIFO processes, and a
    clean clone's suite saw them lag (2.77 s by them, no trip, no status).
    """
    cl, _, log_dir = graph
    t0, t_pub = time.monotonic(), time.time()
    cl.publish(TARGET_M)
    assert cl.spin_for(5.0, lambda: cl.settled(t0)), (
        'not settled: last samples %s (logs %s)' % (cl.ys_since(t0)[-5:], log_dir))
    t_seen = time.monotonic() - t0     # includes 100 samples (0.1 s) inside the band
    after = [(t, y) for t, y in cl.stamped if t > t_pub]
    t_settled = max([t for t, y in after if abs(y - TARGET_M) >= TOL_M], default=t_pub) - t_pub
    print('settled within 0.5 um %.3f s after the setpoint (its stamps; seen by this '
          'client %.3f s after it, 100 samples in the band); peak %.2f um'
          % (t_settled, t_seen, 1e6 * max(y for _, y in after)))
    assert len(after) >= 20 and t_settled < 2.0, cl.explain(t0, log_dir)
    # and it stays (no limit cycle): over 0.5 s most samples in the band (100 % when the
    # machine is quiet; a stalled node on this loaded machine disturbs some)
    t1 = time.monotonic()
    cl.spin_for(0.5)
    assert len(cl.ys_since(t1)) > 50
    cl.check_steady(t1)


def test_a_reader_that_joins_sees_the_present_not_a_replay(graph):
    """
    A reader that joins as ``ros2 topic echo`` does sees the present, not a replay.

    It takes the durability the publishers offer: they are volatile, and the first
    sample it receives is from this moment, not seconds of history.
    """
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    cl, _, _ = graph
    node = cl.node
    for topic in ('/displacement', '/feedforward_voltage', '/feedback_voltage',
                  '/drive_voltage'):
        infos = node.get_publishers_info_by_topic(topic)
        assert infos, topic
        assert all(i.qos_profile.durability == DurabilityPolicy.VOLATILE for i in infos), \
            (topic, [i.qos_profile.durability for i in infos])
    offered = node.get_publishers_info_by_topic('/displacement')[0].qos_profile
    got = []
    t_join = time.time()
    sub = node.create_subscription(
        JointState, 'displacement',
        lambda m: got.append(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec),
        QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE,
                   durability=offered.durability))
    try:
        assert cl.spin_for(5.0, lambda: len(got) >= 10)
        # the stamps are the samples' system-clock times: the first one is from after the
        # join (less one publish-to-receive delay), not the writer's 5 s of history
        assert got[0] > t_join - 0.2, (got[0] - t_join)
    finally:
        node.destroy_subscription(sub)


def test_bad_setpoints_rejected_actuator_stays(graph):
    """NaN, +inf, 1 m and -1 um: each rejected with its reason and a WARN; no motion."""
    cl, _, _ = graph
    t0 = time.monotonic()
    for bad in (math.nan, math.inf, 1.0, -1e-6):
        cl.publish(bad)

    def warns():
        return [(n, m) for t, n, lv, m in cl.diags if t > t0 and lv == WARN
                and 'rejected' in m]

    # the compensator is the one consumer of `setpoint`: it refuses them, and the
    # controller, fed only accepted setpoints (`reference`), never sees them
    nodes = ('hysteresis_compensator',)
    want = ('NaN', '+inf', 'outside', 'outside')
    assert cl.spin_for(5.0, lambda: all(
        sum(w in m for n, m in warns() if n.endswith(node)) >= want.count(w)
        for node in nodes for w in want)), warns()
    cl.spin_for(0.3)
    # both halves of the loop still hold the valid setpoint (diagnostics value, m)
    assert cl.spin_for(2.0, lambda: all(
        float(cl.values.get(node, {}).get('setpoint_m', 'nan')) == TARGET_M
        for node in nodes + ('fuzzy_pid_controller',))), cl.values
    assert not any(n.endswith('fuzzy_pid_controller') for n, m in warns())
    assert len(cl.ys_since(t0)) > 50
    cl.check_steady(t0)         # it stayed
    assert cl.spin_for(5.0, lambda: cl.settled(t0))


def test_wrong_type_publisher_burst_and_odd_service_calls_crash_nothing(graph):
    """
    A wrong-type publisher, a setpoint burst and odd service calls crash no node.

    The wrong-type publisher is named in the compensator's WARN on ``/diagnostics``
    until it goes. The burst: 1,000 setpoints at 1 kHz, a tenth of them invalid. Every
    node keeps running, the drive stays within the driver's limits, and the loop settles
    at the last valid setpoint.
    """
    import rclpy
    from std_msgs.msg import String
    from std_srvs.srv import SetBool, Trigger
    cl, procs, _ = graph
    t0 = time.monotonic()
    # a type clash on the topic, from a participant of its own (as another process would)
    other = rclpy.Context()
    rclpy.init(context=other)
    odd = rclpy.create_node('wrong_type_client', context=other)
    wrong = odd.create_publisher(String, 'setpoint', 10)
    for _ in range(20):
        wrong.publish(String(data='fifty micrometres'))

    def named():
        return [m for t, n, lv, m in cl.diags if t > t0 and n.endswith('hysteresis_compensator')
                and lv == WARN and '/wrong_type_client publishes std_msgs/msg/String' in m]
    # the compensator, which reads /setpoint, names the publisher it never hears from
    # within the discovery of the new participant, one listing of the graph by the
    # sender thread and one check (every 2 s each: ``Health.ENDPOINT_EVERY``)
    assert cl.spin_for(8.0, lambda: named()), [
        (n, m) for t, n, lv, m in cl.diags if t > t0 and lv != OK][-5:]
    print('named on /diagnostics: %s' % named()[-1])
    for i in range(1000):                   # 1 kHz: 10..80 um, every tenth NaN or 1 m
        v = (math.nan if i % 20 == 0 else 1.0) if i % 10 == 0 else (10 + 70 * (i % 7) / 6) * 1e-6
        cl.publish(v)
        cl.spin_for(0.001)
    for name, srv, req in (('fuzzy_pid_controller/reset', Trigger, Trigger.Request()),
                           ('hysteresis_compensator/reset', Trigger, Trigger.Request()),
                           ('hysteresis_compensator/reload_model', Trigger,
                            Trigger.Request()),
                           ('actuator_driver/enable', SetBool, SetBool.Request(data=True)),
                           ('actuator_driver/enable', SetBool, SetBool.Request(data=True))):
        assert cl.call(cl.node.create_client(srv, name), req) is not None, name
    odd.destroy_node()
    rclpy.shutdown(context=other)
    # and the WARN ends once that publisher is gone
    t_gone = time.monotonic()
    assert cl.spin_for(5.0, lambda: any(
        t > t_gone and n.endswith('hysteresis_compensator') and 'wrong type' not in m
        for t, n, lv, m in cl.diags))
    cl.publish(TARGET_M)
    assert cl.spin_for(8.0, lambda: cl.settled(time.monotonic() - 0.2)), (
        cl.ys_since(t0)[-5:], len(cl.ys_since(time.monotonic() - 1.0)), 'samples in 1 s')
    assert all(p.poll() is None for p in procs.values()), 'a node died'
    drives = [v for t, v in cl.drives if t > t0]
    from fiber_align.config import config_path, load_params
    limits = load_params(config_path('driver.yaml'), 'actuator_driver')
    assert drives and min(drives) >= limits['v_min'] - 1e-9, (min(drives), limits['v_min'])
    assert max(drives) <= limits['v_max'] + 1e-9, (max(drives), limits['v_max'])


def test_live_gain_update_accepted_and_rejected(graph):
    """SetParameters: ki0 in range is accepted and used; a negative ki0 is refused."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters
    cl, _, _ = graph
    setp = cl.node.create_client(SetParameters, 'fuzzy_pid_controller/set_parameters')
    getp = cl.node.create_client(GetParameters, 'fuzzy_pid_controller/get_parameters')
    old = cl.call(getp, GetParameters.Request(names=['fuzzy_pid.ki0'])).values[0]
    old_ki = list(old.double_array_value)
    assert len(old_ki) == 2 and old_ki[0] > 0

    def set_ki0(values):
        p = Parameter(name='fuzzy_pid.ki0', value=ParameterValue(
            type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=values))
        return cl.call(setp, SetParameters.Request(parameters=[p])).results[0]

    new_ki = [0.75 * old_ki[0], old_ki[1]]
    res = set_ki0(new_ki)
    assert res.successful, res.reason
    t0 = time.monotonic()
    n0 = len(cl.state)
    cl.spin_for(0.5)
    # controller_state: ki (V/(m s)) now scheduled around the new base (fuzzy +- 10 %)
    ki = [s[3] for s in cl.state[n0:]]
    assert len(ki) > 10      # the client keeps up with only part of the 1 kHz stream
    assert abs(ki[-1] - new_ki[0]) < 0.1 * old_ki[0]
    cl.check_steady(t0)         # bumpless
    assert cl.spin_for(5.0, lambda: cl.settled(t0))

    res = set_ki0([-1.0, old_ki[1]])
    assert not res.successful
    assert 'out of range' in res.reason and 'ki0' in res.reason
    now = cl.call(getp, GetParameters.Request(names=['fuzzy_pid.ki0'])).values[0]
    assert list(now.double_array_value) == new_ki
    assert set_ki0(old_ki).successful


def test_stalled_compensator_trips_and_resumes_without_windup(graph):
    """SIGSTOP the compensator 0.3 s: stale feedforward trips the driver; then no bump."""
    cl, procs, _ = graph
    comp = procs['hysteresis_compensator']
    t0 = time.monotonic()
    comp.send_signal(signal.SIGSTOP)
    try:
        # stale feedforward: the driver trips (ERROR) and ramps to 0 V
        assert cl.spin_for(5.0, lambda: any(
            t > t0 and n.endswith('actuator_driver') and lv == ERROR
            for t, n, lv, m in cl.diags))
        assert cl.spin_for(2.0, lambda: any(t > t0 and v == 0.0 for t, v in cl.drives))
        cl.spin_for(0.3)
    finally:
        comp.send_signal(signal.SIGCONT)
    t1 = time.monotonic()
    assert cl.spin_for(5.0, lambda: any(t > t1 and v > 1.0 for t, v in cl.drives))
    assert cl.spin_for(5.0, lambda: cl.settled(t1)), cl.ys_since(t1)[-5:]
    peak = max(cl.ys_since(t1))
    v_peak = max(v for t, v in cl.drives if t > t1)
    print('stall 0.3 s: resumed, peak %.2f um, drive peak %.1f V, settled %.3f s after '
          'SIGCONT' % (1e6 * peak, v_peak, time.monotonic() - t1))
    # held output, parked nodes: no wound-up integral, which would have driven the
    # amplifier to its 100 V limit (~150 um) on the resume
    assert v_peak < 95.0


@pytest.mark.parametrize('name,bound_m', [('hysteresis_compensator', 80e-6),
                                          ('fuzzy_pid_controller', 62e-6),
                                          ('actuator_driver', 62e-6)])
def test_a_node_stalled_mid_move_does_not_make_the_drive_jump(graph, name, bound_m):
    """
    SIGSTOP the compensator, the controller or the driver 20 ms into a 5 -> 50 um move.

    Before: the compensator caught up the stall's trajectory at once (the feedforward
    jumped: peaks of 107-116 um); the driver, clocked by the feedback, held the drive
    while the controller slept and then jumped (70-74 um); a stalled driver woke to a
    feedforward 20 ms further on (71-85 um). Now the compensator goes on one period
    later (58-62 um), the driver follows the feedforward with the last feedback
    meanwhile (50-53 um), and the trajectory waits while the drive is stale (50-55 um).
    """
    cl, procs, log_dir = graph
    cl.publish(5e-6)
    t_low = time.monotonic()
    assert cl.spin_for(5.0, lambda: len(cl.ys_since(t_low)) > 100 and all(
        abs(y - 5e-6) < TOL_M for y in cl.ys_since(t_low)[-100:])), cl.ys[-3:]
    t0 = time.monotonic()
    cl.publish(TARGET_M)
    cl.spin_for(0.005)
    procs[name].send_signal(signal.SIGSTOP)
    try:
        time.sleep(0.02)
    finally:
        procs[name].send_signal(signal.SIGCONT)
    assert cl.spin_for(5.0, lambda: cl.settled(t0)), cl.explain(t0, log_dir)
    peak, t_peak = max((y, t) for t, y in cl.ys if t > t0)
    print('%s stalled 20 ms mid-move: peak %.2f um' % (name, 1e6 * peak))
    assert peak < bound_m, 'peak %.2f um:\n%s' % (
        1e6 * peak, cl.around(t_peak, log_dir=log_dir))


def test_watchdog_ramps_to_zero_and_restart_recovers(graph):
    """Kill the controller: 0 V within the timeout and ERROR; a restart recovers."""
    from std_srvs.srv import SetBool
    cl, procs, log_dir = graph
    ctl = procs['fuzzy_pid_controller']
    drv = 'actuator_driver'
    # the trips of the earlier tests (the stalled compensator's) must not count towards
    # this test's latch (3 trips within 10 s): the operator's ~/enable clears the history
    res = cl.call(cl.node.create_client(SetBool, drv + '/enable'), SetBool.Request(data=True))
    assert res.success, res.message
    trips_before = int(cl.values.get(drv, {}).get('watchdog_count', '0'))
    t_kill = time.monotonic()
    ctl.kill()
    ctl.wait(timeout=5)
    assert cl.spin_for(5.0, lambda: any(t > t_kill and v == 0.0 for t, v in cl.drives))
    t_zero = min(t for t, v in cl.drives if t > t_kill and v == 0.0) - t_kill
    # watchdog 0.05 s + its 5 ms timer + the ramp (0.5 V/us: one step), seen by this
    # client: typically 0.05-0.15 s here; the bound allows for stalls of this loaded
    # machine (up to 2.3 s seen), the print shows the value
    print('drive at 0 V %.3f s after the kill' % t_zero)
    assert t_zero < 3.0, t_zero
    assert cl.spin_for(3.0, lambda: any(
        t > t_kill and n.endswith('actuator_driver') and lv == ERROR and 'watchdog' in m
        for t, n, lv, m in cl.diags))
    # while the controller is dead the output stays at the safe voltage, held
    cl.spin_for(0.3)
    assert cl.drives[-1][1] == 0.0 and cl.held and cl.held[-1][1]

    # restart: fresh feedback ends the trip (driver OK again); the drive resumes at the
    # feedforward of the held setpoint, and the client's next setpoint closes the loop
    procs['fuzzy_pid_controller'] = spawn('fuzzy_pid_controller', log_dir)
    t_start = time.monotonic()
    assert cl.spin_for(30, lambda: cl.matched()
                       and any(t > t_start and v > 1.0 for t, v in cl.drives)), (
        'no drive after the restart: driver %s; last driver status %s; logs %s' % (
            cl.values.get(drv), [m for t, n, lv, m in cl.diags if n.endswith(drv)][-1:],
            log_dir))
    # OK once the trip's ERROR (held 2 s on /diagnostics) has expired; with two CPU hogs
    # about one restart in eight trips once more just after the resume (a 50 ms stall of
    # the loaded machine), which starts its own 2 s
    assert cl.spin_for(6.0, lambda: any(
        t > t_start and n.endswith('actuator_driver') and lv == OK
        for t, n, lv, m in cl.diags)), cl.explain(t_kill, log_dir)
    cl.spin_for(0.3)
    ys = cl.ys_since(time.monotonic() - 0.1)
    print('feedforward alone after the restart: %.3f um' % (1e6 * sum(ys) / len(ys)))
    t0 = time.monotonic()
    # no re-send: the restarted controller takes the held setpoint from the latched
    # `reference` of the compensator
    assert cl.spin_for(5.0, lambda: cl.settled(t0)), cl.explain(t_kill, log_dir)
    print('recovered without a re-send: settled %.3f s after the restart; watchdog trips '
          'since the kill: %d' % (time.monotonic() - t_start, int(
              cl.values[drv]['watchdog_count']) - trips_before))
    ys = cl.ys_since(t_kill)
    t_peak = max((y, t) for t, y in cl.ys if t > t_kill)[1]
    t_low = min((y, t) for t, y in cl.ys if t > t_kill)[1]
    print('displacement since the kill: %.2f..%.2f um, the peak %.3f s and the low %.3f s '
          'after the restart' % (1e6 * min(ys), 1e6 * max(ys), t_peak - t_start,
                                 t_low - t_start))
    assert max(ys) <= 90e-6 + 2e-6, 'peak %.2f um:\n%s' % (
        1e6 * max(ys), cl.around(t_peak, log_dir=log_dir))
    assert min(ys) >= -2e-6, 'low %.2f um:\n%s' % (
        1e6 * min(ys), cl.around(t_low, log_dir=log_dir))


def test_a_stalled_plant_applies_the_ramp_it_slept_through(graph):
    """SIGSTOP the plant 0.3 s at 50 um: the driver's ramp to 0 V reaches it as a ramp."""
    cl, procs, log_dir = graph
    cl.rearm_and_settle()
    plant = procs['simulated_actuator']
    t0 = time.monotonic()
    plant.send_signal(signal.SIGSTOP)
    try:
        # no samples, so neither input of the driver: it trips and ramps to 0 V while
        # the plant sleeps (the ramp takes 26 ms at 2000 V/s)
        assert cl.spin_for(5.0, lambda: any(t > t0 and v == 0.0 for t, v in cl.drives))
        cl.spin_for(0.2)
    finally:
        plant.send_signal(signal.SIGCONT)
    t1 = time.monotonic()
    assert cl.spin_for(5.0, lambda: len(cl.ys_since(t1)) > 200)
    ys = cl.ys_since(t1)
    t_low = min((y, t) for t, y in cl.ys if t > t1)[1]
    print('stalled plant: displacement after SIGCONT %.2f..%.2f um'
          % (1e6 * min(ys), 1e6 * max(ys)))
    # a plant that applied only the newest drive on waking would step 52 V -> 0 V at
    # once and ring the bending mode to about -20 um
    assert min(ys) >= -2e-6, 'low %.2f um:\n%s' % (
        1e6 * min(ys), cl.around(t_low, log_dir=log_dir))
    assert cl.spin_for(8.0, lambda: cl.settled(t1)), cl.explain(t0, log_dir)
    assert max(cl.ys_since(t1)) <= 90e-6 + 2e-6
    # the stall cost the last 10 s more than the goal (0.1 %) of the periods (a late
    # tick's periods are missed even while the tripped driver holds): a WARN says so, in
    # one of the plant's reports (every diagnostics_period_s) of the 10 s window
    assert cl.spin_for(3.0, lambda: any(
        t > t1 and n.endswith('simulated_actuator') and lv == WARN
        and 'of the cycles in the last' in m and '(goal <= 0.1 %)' in m
        for t, n, lv, m in cl.diags)), [
        (n, lv, m) for t, n, lv, m in cl.diags if n.endswith('simulated_actuator')][-3:]


def test_a_stalled_driver_ramps_to_zero_in_steps_not_in_one_jump(graph):
    """Kill the controller, then stall the driver 30 ms at a time: the ramp stays a ramp."""
    cl, procs, log_dir = graph
    cl.rearm_and_settle()
    drv = procs['actuator_driver']
    t_kill = time.monotonic()
    procs['fuzzy_pid_controller'].kill()
    procs['fuzzy_pid_controller'].wait(timeout=5)
    try:
        # the trip comes 50 ms after the kill and its ramp takes 26 ms: stalls of 30 ms
        # for 0.5 s cover both; a ramp that made up a stall at once would step 52 V down
        while time.monotonic() - t_kill < 0.5:
            drv.send_signal(signal.SIGSTOP)
            cl.spin_for(0.03)
            drv.send_signal(signal.SIGCONT)
            cl.spin_for(0.004)
    finally:
        drv.send_signal(signal.SIGCONT)
    assert cl.spin_for(5.0, lambda: any(t > t_kill and v == 0.0 for t, v in cl.drives))
    cl.spin_for(0.3)
    after = [v for t, v in cl.drives if t > t_kill]     # a reliable reader: every value
    drops = [a - b for a, b in zip(after, after[1:])]
    ys = cl.ys_since(t_kill)
    print('stalled driver: largest drive step down %.1f V, displacement %.2f..%.2f um'
          % (max(drops), 1e6 * min(ys), 1e6 * max(ys)))
    assert min(ys) >= -2e-6, min(ys)
    assert max(drops) <= 2.0 + 1e-9, max(drops)   # 2000 V/s for one 1 ms period
