# SPDX-License-Identifier: Apache-2.0
"""
The driver's watch of its inputs' publishers holds before a foreign message is served.

The matched event of a second publisher is served by the executor when it comes round to
it; on a loaded machine (a clean clone's suite) the foreign messages came first and the
driver applied 100 V for 0.3 s. Each message now reads the match count first (issue 39.1).
"""

import time

import pytest

pytestmark = pytest.mark.ros


def _setup(ctx, publishers):
    import rclpy
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros import bus as b
    from fiber_align.nodes.ros.owners import PublisherWatch
    from fiber_align.nodes.ros.qos import LIVE_QOS
    context, nodes = ctx
    node = rclpy.create_node('watched_driver', context=context)
    nodes.append(node)
    found, served = [], []
    # a long period: the thread's count does not run before the message is served
    watch = PublisherWatch(node, {'cmd': '/compensator'}, found.append, period_s=30.0)
    sub = b.subscription(node, Float64, 'cmd', lambda m: served.append((len(found), m.data)),
                         LIVE_QOS, None, watch)
    pubs = []
    for name in publishers:
        pub_node = rclpy.create_node(name, context=context)
        nodes.append(pub_node)
        pubs.append(pub_node.create_publisher(Float64, 'cmd', LIVE_QOS))
    t_end = time.monotonic() + 10.0
    while sub.get_publisher_count() < len(publishers) and time.monotonic() < t_end:
        time.sleep(0.01)            # matched by DDS; the node is never spun: no event served
    assert sub.get_publisher_count() == len(publishers)
    return watch, sub, found, served, Float64


def test_a_second_publisher_holds_before_its_first_message_is_served(ctx):
    watch, sub, found, served, Float64 = _setup(ctx, ['compensator', 'intruder'])
    try:
        sub.callback(Float64(data=100.0))
        # the finding reached the driver before the message did
        assert served == [(1, 100.0)]
        assert watch.pending
        assert found[0] == ['/cmd: 2 publishers matched, 1 expected']
        sub.callback(Float64(data=100.0))
        assert len(found) == 1      # told once
    finally:
        watch.close()


def test_one_publisher_is_no_finding(ctx):
    watch, sub, found, served, Float64 = _setup(ctx, ['compensator'])
    try:
        for v in (1.0, 2.0, 3.0):
            sub.callback(Float64(data=v))
        assert served == [(0, 1.0), (0, 2.0), (0, 3.0)]
        assert found == [] and not watch.pending
    finally:
        watch.close()


def test_a_message_taken_before_its_subscription_was_destroyed_is_served(ctx):
    """
    Serve a message whose subscription was destroyed after the take, as before.

    A lifecycle cleanup (the amplifier unplugged) can destroy it between the take and
    the call: the count is not read (the hardware rig's control process died of
    InvalidHandle in a clean clone's suite).
    """
    watch, sub, found, served, Float64 = _setup(ctx, ['compensator'])
    try:
        ctx[1][0].destroy_subscription(sub)
        sub.callback(Float64(data=5.0))
        assert served == [(0, 5.0)] and found == []
    finally:
        watch.close()


#: a node destroyed under its running watch, many times over, in a process of its own
_DESTROYED_UNDER_THE_WATCH = r'''
import threading, time
import rclpy
from fiber_align.nodes.ros.owners import PublisherWatch
rclpy.init()
threads = []
for i in range(40):
    node = rclpy.create_node('watched_%d' % i)
    w = PublisherWatch(node, {'cmd': '/compensator'}, lambda lines: None, period_s=0.001)
    time.sleep(0.005)
    node.destroy_node()             # without w.close(): the thread meets a destroyed node
    threads.append(w._thread)
    for _ in range(50):             # each allocation may reuse the freed node's memory
        rclpy.create_node('filler_%d_%d' % (i, _)).destroy_node()
time.sleep(0.1)
print('alive', sum(t.is_alive() for t in threads), flush=True)
'''


def test_a_node_destroyed_under_a_running_watch_ends_its_thread_not_the_process():
    """
    The watch's thread holds the node in use over each count (rcl by ctypes).

    It read the node's raw pointer after the node was freed: a clean clone's full suite
    died of SIGSEGV in ``rcl_count_publishers`` from that thread (core dump, 2026-12-07).
    """
    import subprocess
    import sys
    p = subprocess.run([sys.executable, '-c', _DESTROYED_UNDER_THE_WATCH],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, (p.returncode, p.stderr[-2000:])
    assert 'alive 0' in p.stdout, p.stdout
