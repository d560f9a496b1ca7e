# SPDX-License-Identifier: Apache-2.0
"""
The graph on one host and a ROS client on another, found by ROS's own discovery rules.

Two network namespaces joined by a veth pair stand in for the rig PC (``a``: the graph
under ``bringup --scenario none``) and the workstation (``b``: an rclpy client). The
client must see the graph's nodes, publish a 50 um setpoint on ``setpoint`` and read
``displacement`` reach it within 1 um. Case ``subnet``: ROS's defaults (no discovery
variable set: SUBNET in Jazzy) on both sides, one test-unique ``ROS_DOMAIN_ID``. Case
``static_peers``: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and ``ROS_STATIC_PEERS`` set
to the other side's address on both sides. Case ``localhost``: the graph LOCALHOST-only,
the client on ROS's defaults: it sees none of the graph's nodes (the namespaces do
separate the hosts, so the cases above prove discovery over the link).

Needs root and ``ip netns`` (CI runs as root): without them the test fails, naming why.
Every process started in a namespace is killed by pid and every namespace and link is
deleted by name at teardown, also when the test fails.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from fiber_align.graph.description import control_nodes

pytestmark = pytest.mark.ros

#: The setpoint the workstation publishes (m) and the tolerance on the reading (m).
TARGET_M = 50e-6
TOLERANCE_M = 1e-6
#: Bounds (wall s): the graph up in its namespace; the client's whole run.
GRAPH_UP_S = 90.0
CLIENT_S = 60.0
#: How long the client looks for the graph in the case where it must not find it (s):
#: four times the slowest finding where it must (static peers, about 1 s: the graph's
#: participants announce themselves every 1 s; SUBNET about 0.3 s).
UNSEEN_S = 4.0
#: The variables that choose ROS discovery; each case sets its own on both sides.
DISCOVERY_VARS = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY')

CLIENT = textwrap.dedent('''
    import json, sys, time
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    want, target, tol, bound = set(sys.argv[1].split(',')), *map(float, sys.argv[2:5])
    rclpy.init()
    node = rclpy.create_node('workstation_probe')
    end = time.monotonic() + bound
    out = {'nodes': [], 'matched': False, 'last_m': None, 'reached': False}
    while time.monotonic() < end and not want <= set(out['nodes']):
        rclpy.spin_once(node, timeout_sec=0.1)
        out['nodes'] = sorted({n for n, _ in node.get_node_names_and_namespaces()})
    out['seen_s'] = bound - (end - time.monotonic())
    if want <= set(out['nodes']) and target == target:
        samples = []
        # best effort and volatile: matches whatever reliability and durability the graph
        # publishes with, and reads only what is sent from now on
        node.create_subscription(JointState, 'displacement',
                                 lambda m: samples.append(m.position[0]),
                                 qos_profile_sensor_data)
        pub = node.create_publisher(Float64, 'setpoint', 10)
        while time.monotonic() < end and pub.get_subscription_count() == 0:
            rclpy.spin_once(node, timeout_sec=0.05)
        out['matched'] = pub.get_subscription_count() > 0
        sent = -1.0
        while time.monotonic() < end and out['matched']:
            if time.monotonic() - sent > 1.0:    # again, in case the first met a new match
                pub.publish(Float64(data=target))
                sent = time.monotonic()
            rclpy.spin_once(node, timeout_sec=0.05)
            if samples:
                out['last_m'] = samples[-1]
                if abs(samples[-1] - target) <= tol:
                    out['reached'] = True
                    break
        # one more second of samples: the stream goes on (and what it costs the link)
        n, t1 = len(samples), time.monotonic() + 1.0
        while out['reached'] and time.monotonic() < t1:
            rclpy.spin_once(node, timeout_sec=0.05)
        out['samples_1s'] = len(samples) - n
    out['elapsed_s'] = bound - (end - time.monotonic())
    print('RESULT ' + json.dumps(out), flush=True)
    node.destroy_node()
    rclpy.shutdown()
''')


def _ip(*args, check=True):
    """Run ``ip ARGS`` (bounded); return the finished process."""
    proc = subprocess.run(['ip', *args], capture_output=True, text=True, timeout=20)
    if check and proc.returncode != 0:
        pytest.fail('`ip %s` failed (exit %d): %s'
                    % (' '.join(args), proc.returncode, proc.stderr.strip()), pytrace=False)
    return proc


class Hosts:
    """Two network namespaces joined by a veth pair: names, addresses, processes in them."""

    def __init__(self):
        """Choose names and addresses unique to this pytest process."""
        pid = os.getpid()
        self.ns = {'a': 'fa%da' % pid, 'b': 'fa%db' % pid}
        self.link = {'a': 'fv%da' % pid, 'b': 'fv%db' % pid}     # at most 15 characters
        net = '10.231.%d' % (pid % 250)
        self.addr = {'a': net + '.1', 'b': net + '.2'}
        self.procs = []

    def create(self):
        """Create both namespaces, the veth pair between them, ``lo`` and the link up."""
        for side in 'ab':
            _ip('netns', 'add', self.ns[side])
        _ip('link', 'add', self.link['a'], 'netns', self.ns['a'], 'type', 'veth',
            'peer', 'name', self.link['b'], 'netns', self.ns['b'])
        for side in 'ab':
            ns = self.ns[side]
            _ip('-n', ns, 'addr', 'add', self.addr[side] + '/24', 'dev', self.link[side])
            _ip('-n', ns, 'link', 'set', 'lo', 'up')
            _ip('-n', ns, 'link', 'set', self.link[side], 'up', 'multicast', 'on')

    def start(self, side, argv, env, log):
        """Start ``argv`` in namespace ``side`` (own process group), output to ``log``."""
        with open(log, 'w') as out:
            proc = subprocess.Popen(['ip', 'netns', 'exec', self.ns[side], *argv], env=env,
                                    stdout=out, stderr=subprocess.STDOUT,
                                    start_new_session=True)
        self.procs.append(proc)
        return proc

    def received(self, side):
        """Return the packets received so far on ``side``'s end of the veth pair."""
        out = _ip('-n', self.ns[side], '-s', '-j', 'link', 'show', 'dev', self.link[side])
        return int(json.loads(out.stdout)[0]['stats64']['rx']['packets'])

    def destroy(self):
        """Stop every process (SIGINT, then SIGKILL by pid), delete the links and namespaces."""
        for proc in self.procs:
            _signal_group(proc, signal.SIGINT)
        end = time.monotonic() + 10.0
        for proc in self.procs:
            try:
                proc.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                _signal_group(proc, signal.SIGKILL)
                proc.wait(timeout=5)
        for side in 'ab':       # anything left in a namespace (bringup's own sessions)
            listed = _ip('netns', 'pids', self.ns[side], check=False).stdout.split()
            for pid in listed:
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except ProcessLookupError:
                    pass
        for side in 'ab':
            _ip('-n', self.ns[side], 'link', 'del', self.link[side], check=False)
        for side in 'ab':
            _ip('netns', 'del', self.ns[side], check=False)
        left = _ip('netns', 'list', check=False).stdout
        assert not any(ns in left.split() for ns in self.ns.values()), left


def _signal_group(proc, sig):
    """Send ``sig`` to ``proc``'s process group if it still runs."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass


@pytest.fixture
def hosts():
    """Yield :class:`Hosts` (created); tear everything down afterwards, also on failure."""
    if os.geteuid() != 0:
        pytest.fail('test_across_hosts needs root for `ip netns` (CI runs as root); '
                    'running as uid %d' % os.geteuid(), pytrace=False)
    if shutil.which('ip') is None:
        pytest.fail('test_across_hosts needs `ip` (iproute2) with `ip netns`', pytrace=False)
    h = Hosts()
    try:
        h.create()
        yield h
    finally:
        h.destroy()


def _env(side_vars):
    """Return the environment of one side: os.environ without discovery variables, + own."""
    env = {k: v for k, v in os.environ.items() if k not in DISCOVERY_VARS}
    env.update(side_vars, PYTHONUNBUFFERED='1')
    return env


def _wait_graph_up(proc, log):
    """Wait (bounded) until bringup in its namespace prints that the graph is up."""
    end = time.monotonic() + GRAPH_UP_S
    while time.monotonic() < end:
        text = log.read_text() if log.exists() else ''
        if 'bringup: graph up' in text:
            return
        if proc.poll() is not None:
            pytest.fail('the graph exited (%s) before it was up:\n%s'
                        % (proc.returncode, text[-3000:]), pytrace=False)
        time.sleep(0.2)
    pytest.fail('the graph was not up within %g s:\n%s'
                % (GRAPH_UP_S, log.read_text()[-3000:]), pytrace=False)


def _client(hosts, env, tmp_path, bound_s, target_m):
    """Run the workstation client in namespace ``b``; return its RESULT mapping."""
    script = tmp_path / 'workstation.py'
    script.write_text(CLIENT)
    log = tmp_path / 'workstation.log'
    proc = hosts.start('b', [sys.executable, str(script), ','.join(control_nodes('none')),
                             repr(target_m), repr(TOLERANCE_M), repr(bound_s)], env, log)
    try:
        proc.wait(timeout=bound_s + 30.0)
    except subprocess.TimeoutExpired:
        pytest.fail('the client did not end within %g s:\n%s'
                    % (bound_s + 30.0, log.read_text()[-3000:]), pytrace=False)
    text = log.read_text()
    lines = [ln for ln in text.splitlines() if ln.startswith('RESULT ')]
    assert proc.returncode == 0 and lines, text[-3000:]
    return json.loads(lines[-1][len('RESULT '):])


CASES = {
    # name: (the graph's discovery variables, the client's), 'b'/'a' the other's address
    'subnet': ({}, {}),
    'static_peers': ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_STATIC_PEERS': 'b'},
                     {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_STATIC_PEERS': 'a'}),
    'localhost': ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}, {}),
}


@pytest.mark.parametrize('case', sorted(CASES))
def test_workstation_commands_the_rig_across_hosts(hosts, tmp_path, case):
    """The client in ``b`` finds the graph in ``a`` by ROS's rules and moves the actuator."""
    graph_vars, client_vars = (
        {k: hosts.addr.get(v, v) if k == 'ROS_STATIC_PEERS' else v for k, v in d.items()}
        for d in CASES[case])
    log = tmp_path / 'graph.log'
    graph = hosts.start('a', [sys.executable, '-m', 'fiber_align.bringup',
                              '--scenario', 'none', '--quiet'], _env(graph_vars), log)
    t0 = time.monotonic()
    _wait_graph_up(graph, log)
    up_s = time.monotonic() - t0
    seen = ', '.join('%s=%s' % kv for kv in sorted(graph_vars.items())) or 'ROS defaults'
    if case == 'localhost':
        r = _client(hosts, _env(client_vars), tmp_path, UNSEEN_S, float('nan'))
        print('%s: graph up in %.1f s; the workstation saw %s in %.1f s'
              % (case, up_s, r['nodes'], r['elapsed_s']))
        assert not set(control_nodes('none')) & set(r['nodes']), \
            'a LOCALHOST graph was seen from the other host: %s' % r
        return
    rx0 = hosts.received('b')
    r = _client(hosts, _env(client_vars), tmp_path, CLIENT_S, TARGET_M)
    rx = hosts.received('b') - rx0
    print('%s (%s): graph up in %.1f s; nodes seen in %.1f s, %.2f um for %.2f um, '
          '%.1f s in all, %d packets received over the link, %d samples in the last 1 s'
          % (case, seen, up_s, r['seen_s'], (r['last_m'] or float('nan')) * 1e6,
             TARGET_M * 1e6, r['elapsed_s'], rx, r.get('samples_1s', -1)))
    assert set(control_nodes('none')) <= set(r['nodes']), r
    assert r['matched'], 'the setpoint publisher matched no subscriber: %s' % r
    assert r['reached'], ('displacement did not reach %g m within %g m: %s (the graph\'s '
                          'summary, watchdog trips included, is in %s after teardown)'
                          % (TARGET_M, TOLERANCE_M, r, log))
    assert graph.poll() is None, log.read_text()[-3000:]
