# SPDX-License-Identifier: Apache-2.0
"""Run the ``bag_recorder`` executable, publish to it, stop it, and read its bag."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import rclpy  # noqa: E402 - a hard dependency of the recorder tests

from fiber_align.analysis import bag as bagio  # noqa: E402

N = 200
pytestmark = pytest.mark.ros


def _start(out, storage, ns=''):
    """Start the recorder process; return it."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    cmd = [sys.executable, '-m', 'fiber_align.nodes.bag_recorder', '--ros-args',
           '-p', 'output:=%s' % out, '-p', 'storage:=%s' % storage,
           '-p', 'discovery_period_s:=0.05']
    if ns:
        cmd += ['-r', '__ns:=/%s' % ns.strip('/')]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def _wait(cond, timeout, what, spin=None):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if spin is not None:
            rclpy.spin_once(spin, timeout_sec=0.05)
        else:
            time.sleep(0.05)
        if cond():
            return
    raise AssertionError('timed out after %g s waiting for %s' % (timeout, what))


def _record(tmp_path, storage, sig, ns='', settle_s=0.0):
    """Publish N Float64 and N JointState messages to a recorder, stop it with ``sig``."""
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    out = tmp_path / ('bag_' + storage)
    rclpy.init()
    node = rclpy.create_node('recorder_test_pub', namespace=ns or '/')
    proc = _start(str(out), storage, ns)
    try:
        qos = QoSProfile(depth=N)
        p1 = node.create_publisher(Float64, 'reference', qos)
        p2 = node.create_publisher(JointState, 'displacement', qos)
        _wait(lambda: p1.get_subscription_count() >= 1 and p2.get_subscription_count() >= 1,
              20.0, 'the recorder to subscribe', node)
        for i in range(N):
            p1.publish(Float64(data=i * 1e-6))
            js = JointState(name=['bimorph_tip'], position=[i * 1e-7], velocity=[0.0])
            js.header.stamp.sec, js.header.stamp.nanosec = 0, i * 1000000
            p2.publish(js)
        assert p1.wait_for_all_acked(rclpy.duration.Duration(seconds=5.0))
        assert p2.wait_for_all_acked(rclpy.duration.Duration(seconds=5.0))
        time.sleep(settle_s)
        proc.send_signal(sig)
        outs, _ = proc.communicate(timeout=20)
        want = -signal.SIGKILL if sig == signal.SIGKILL else 0
        assert proc.returncode == want, outs.decode(errors='replace')
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
        node.destroy_node()
        rclpy.try_shutdown()
    return out


def _check(out, ns=''):
    prefix = '/' + ns.strip('/') + '/' if ns else '/'
    streams, lockstep, topics = bagio.read_streams(out)
    assert not lockstep
    assert topics[prefix + 'reference'] == ('std_msgs/msg/Float64', N)
    assert topics[prefix + 'displacement'] == ('sensor_msgs/msg/JointState', N)
    assert np.array_equal(streams['setpoint'].fields['data'], np.arange(N) * 1e-6)
    assert np.array_equal(streams['displacement'].fields['position'], np.arange(N) * 1e-7)
    assert np.array_equal(streams['displacement'].fields['stamp_ns'], np.arange(N) * 1000000)
    counts = json.loads((out / 'recorder_counts.json').read_text())
    counts.pop('/diagnostics', None)    # the recorder's own reports, when asked for
    assert counts == {prefix + 'reference': N, prefix + 'displacement': N}
    assert json.loads((out / 'recorder_events.json').read_text()) == {
        'lost': 0, 'incompatible_qos': 0}


def test_recorder_sigint_mcap(tmp_path):
    """SIGINT finalises an mcap bag holding every published message."""
    out = _record(tmp_path, 'mcap', signal.SIGINT)
    assert (out / 'metadata.yaml').is_file()
    _check(out)


def test_recorder_sigterm_sqlite3_namespace(tmp_path):
    """SIGTERM finalises a sqlite3 bag; relative topics resolve in the recorder's namespace."""
    out = _record(tmp_path, 'sqlite3', signal.SIGTERM, ns='rig1')
    _check(out, 'rig1')


def test_recorder_sigkill_mcap_is_repaired(tmp_path):
    """SIGKILL leaves no summary; bag-repair recovers every message flushed before it."""
    out = _record(tmp_path, 'mcap', signal.SIGKILL, settle_s=1.5)   # > flush_period_s
    assert not (out / 'metadata.yaml').exists()
    with pytest.raises(Exception):
        bagio.read_streams(out)
    env = dict(os.environ)
    rep = subprocess.run([sys.executable, '-m', 'fiber_align.cli', 'bag-repair', str(out)],
                         env=env, capture_output=True, text=True, timeout=60)
    assert rep.returncode == 0, rep.stderr
    fixed = out.with_name(out.name + '_repaired')
    streams, _, topics = bagio.read_streams(fixed)
    assert topics['/reference'] == ('std_msgs/msg/Float64', N)
    assert topics['/displacement'] == ('sensor_msgs/msg/JointState', N)
    assert np.array_equal(streams['displacement'].fields['position'], np.arange(N) * 1e-7)
    # and analyze reads it
    ana = subprocess.run([sys.executable, '-m', 'fiber_align.cli', 'analyze', str(fixed),
                          '--json'], env=env, capture_output=True, text=True, timeout=120)
    assert ana.returncode == 0, ana.stderr


def test_in_process_recorder_takes_every_bus_message_without_dds(tmp_path):
    """Hosted on a LocalBus, the recorder writes every message of its process's nodes."""
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from fiber_align.nodes.bag_recorder import BagRecorder
    from fiber_align.nodes.ros.bus import LocalBus, Pub
    from fiber_align.nodes.ros.qos import REALTIME_QOS
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    out = tmp_path / 'bag'
    pub_node = rclpy.create_node('plant', namespace='/st', context=ctx)
    bus = LocalBus()
    bus.provide('/st/displacement', '/st/reference')
    rec = None
    try:
        disp = Pub(pub_node, JointState, 'displacement', REALTIME_QOS, bus)
        ref = Pub(pub_node, Float64, 'reference', REALTIME_QOS, bus)
        rec = BagRecorder(bus=bus, context=ctx, namespace='/st', parameter_overrides=[
            Parameter('output', value=str(out)),
            Parameter('topics', value=['displacement', 'reference'])])
        assert set(rec.local) == {'/st/displacement', '/st/reference'}
        assert not rec.subs        # nothing of them through DDS
        js = JointState(name=['bimorph_tip'], position=[0.0], velocity=[0.0])
        f = Float64()
        for k in range(N):      # a node reuses its message objects, as the loop's do
            js.header.stamp.sec, js.header.stamp.nanosec = divmod(k * 1000000, 10 ** 9)
            js.position[0] = k * 1e-7
            disp.publish(js)
            f.data = k * 1e-6
            ref.publish(f)
            bus.slack.after_cycle()
        rec.close()
    finally:
        if rec is not None:
            rec.destroy_node()
        pub_node.destroy_node()
        ctx.try_shutdown()
    _check(out, 'st')
