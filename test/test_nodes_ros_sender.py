# SPDX-License-Identifier: Apache-2.0
"""The publish thread (``nodes.ros.sender``): a publish that waits in DDS holds up nobody."""

import ctypes
import time

import pytest

pytestmark = pytest.mark.ros


@pytest.fixture
def node():
    """Yield an rclpy node on its own context (shut down after the test)."""
    import rclpy
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    n = rclpy.create_node('sender_test', context=ctx)
    try:
        yield n
    finally:
        n.destroy_node()
        ctx.try_shutdown()


def _reader(node, topic, depth=5000):
    from std_msgs.msg import Float64
    got = []
    node.create_subscription(Float64, topic, lambda m: got.append(m.data), depth)
    return got


def _spin_until(node, cond, timeout_s):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.01)
    ex.remove_node(node)
    assert rclpy.ok(context=node.context)
    return cond()


def _slow_publish(rcl, delay_s):
    """
    Wrap the thread's publish: the first call waits ``delay_s`` without the GIL.

    As a publish that waits on Fast DDS's lock does inside rcl.
    """
    libc = ctypes.CDLL(None)
    real = rcl.publish
    state = {'slowed': 0}

    def publish(ptr, ser, alloc):
        if not state['slowed']:
            state['slowed'] = 1
            libc.usleep(int(delay_s * 1e6))
        return real(ptr, ser, alloc)
    rcl.publish = publish
    return state


def test_every_message_arrives_in_order_across_topics(node):
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.sender import Sender
    from fiber_align.nodes.ros.qos import sample_pub_qos
    qos = sample_pub_qos(False)
    a, b = node.create_publisher(Float64, 'a', qos), node.create_publisher(Float64, 'b', qos)
    got_a, got_b = _reader(node, 'a'), _reader(node, 'b')
    s = Sender()
    wa, wb = s.writer(a, True), s.writer(b, True)
    assert s.start()
    try:
        assert _spin_until(node, lambda: wa.readers and wb.readers or s._refresh(), 5.0)
        for i in range(2000):
            (wa if i % 2 else wb).publish(Float64(data=float(i)))
        assert _spin_until(node, lambda: len(got_a) + len(got_b) == 2000, 10.0)
    finally:
        assert s.stop() == 0
    assert got_a == [float(i) for i in range(1, 2000, 2)]
    assert got_b == [float(i) for i in range(0, 2000, 2)]
    assert s.published == 2000 and s.dropped == 0 and s.failed == 0


def test_a_publish_that_waits_in_dds_does_not_hold_up_the_publishing_loop(node):
    """A 1 kHz loop publishing through a writer whose DDS publish waits 0.3 s."""
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.sender import Sender
    from fiber_align.nodes.ros.qos import sample_pub_qos
    pub = node.create_publisher(Float64, 'a', sample_pub_qos(False))
    got = _reader(node, 'a')
    s = Sender()
    w = s.writer(pub, True)
    assert s.start()
    slowed = _slow_publish(s._rcl, 0.3)
    gaps = []
    try:
        assert _spin_until(node, lambda: w.readers or s._refresh(), 5.0)
        t_prev = time.monotonic()
        for i in range(600):
            w.publish(Float64(data=float(i)))
            time.sleep(0.001)
            t = time.monotonic()
            gaps.append(t - t_prev)
            t_prev = t
        assert _spin_until(node, lambda: len(got) == 600, 10.0)
    finally:
        assert s.stop() == 0
    assert slowed['slowed'] == 1
    # the loop's own periods (1 ms sleep plus scheduling), never the 0.3 s of the wait
    assert max(gaps) < 0.1, max(gaps)
    assert got == [float(i) for i in range(600)]
    assert s.backlog_max > 50        # the messages of the wait queued, none lost


def test_without_the_thread_the_same_wait_holds_up_the_loop(node):
    """The baseline of the test above: the same publish on the loop's thread, same wait."""
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.rcl_ctypes import MessageType, Rcl
    from fiber_align.nodes.ros.qos import sample_pub_qos
    pub = node.create_publisher(Float64, 'a', sample_pub_qos(False))
    rcl = Rcl()
    _slow_publish(rcl, 0.3)
    ctype = MessageType(Float64)
    msg = ctype.to_c(Float64(data=1.0))
    t0 = time.monotonic()
    assert rcl.publish(pub.handle.pointer, msg, None) == 0
    ctype.destroy(msg)
    assert time.monotonic() - t0 >= 0.29


def test_the_bytes_on_the_wire_are_rclpys_and_strict_cdr_readers_take_them(node):
    """A JointState through the sender: the same bytes as rclpy's publish, rosbags reads it."""
    from rosbags.typesys import get_typestore, Stores
    from sensor_msgs.msg import JointState

    from fiber_align.nodes.ros.sender import Sender
    pub = node.create_publisher(JointState, 'js', 10)
    raw = []
    node.create_subscription(JointState, 'js', raw.append, 10, raw=True)
    js = JointState()
    js.header.stamp.sec, js.header.stamp.nanosec = 12, 345
    js.name, js.position, js.velocity = ['bimorph_tip'], [1.5e-5], [-2e-3]
    s = Sender()
    w = s.writer(pub, False)
    assert _spin_until(node, lambda: pub.get_subscription_count() > 0, 5.0)
    pub.publish(js)                       # rclpy on this thread
    assert s.start()
    try:
        w.publish(js)                     # the sender's thread
        assert _spin_until(node, lambda: len(raw) == 2, 5.0)
    finally:
        assert s.stop() == 0
    assert raw[0] == raw[1]
    back = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(raw[1], 'sensor_msgs/msg/JointState')
    assert list(back.position) == [1.5e-5] and back.header.stamp.nanosec == 345


def test_a_full_queue_drops_the_oldest_and_counts_them(node):
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.sender import Sender
    pub = node.create_publisher(Float64, 'a', 10)
    s = Sender(max_queued=100)
    w = s.writer(pub, False)
    s.running = True            # queue without a thread: nothing drains
    for i in range(150):
        w.publish(Float64(data=float(i)))
    s.running = False
    assert s.dropped == 50 and len(s._q) == 100
    assert s.stats()['sender.dropped'] == 50


def test_a_forgotten_writer_publishes_nothing_more(node):
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.sender import Sender
    pub = node.create_publisher(Float64, 'a', 10)
    s = Sender()
    w = s.writer(pub, False)
    s.running = True
    w.publish(Float64(data=1.0))
    s.forget(w)
    s.running = False
    assert w.ptr is None and w.sender is None
    s._rcl = None
    assert s.start()             # the queued message of the forgotten writer is dropped
    assert s.stop() == 0
    assert s.dropped == 1 and s.published == 0


def test_a_durable_writer_without_readers_sends_its_newest_once_per_refresh(node):
    """A latched topic set every period: few DDS publishes, a late reader gets the present."""
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.qos import CONTROL_QOS, LATCHED_QOS
    from fiber_align.nodes.ros.sender import Sender
    pub = node.create_publisher(Float64, 'latched', LATCHED_QOS)
    s = Sender(refresh_s=0.01)
    w = s.writer(pub, False)
    assert s.start()
    try:
        assert w.readers == 0
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 0.5:      # 1 kHz for 0.5 s, nobody listening
            w.publish(Float64(data=float(n)))
            n += 1
            time.sleep(0.001)
        newest = float(n - 1)
        time.sleep(0.05)
        # about one publish per refresh (10 ms), not one per message
        assert 0 < s.published < n / 4, (s.published, n)
        got = []
        # deep and durable: every message of the burst below is kept
        node.create_subscription(Float64, 'latched', lambda m: got.append(m.data),
                                 CONTROL_QOS)
        assert _spin_until(node, lambda: got and got[-1] == newest, 5.0), (got, newest)
        # once the sender has seen the reader (one refresh), every message is published
        assert _spin_until(node, lambda: w.readers > 0, 5.0)
        before = s.published
        for i in range(100):
            w.publish(Float64(data=1000.0 + i))
        assert _spin_until(node, lambda: got[-1] == 1099.0, 5.0)
        assert got[-100:] == [1000.0 + i for i in range(100)]
        # counted after rcl_publish returns: the reader may have the last one first
        assert _spin_until(node, lambda: s.published - before >= 100, 5.0), (
            s.published, before)
    finally:
        s.stop()


def test_a_kept_one_value_message_is_the_value_at_its_publish(node):
    """
    A Float64 kept without readers is its value, not a C copy: read at the publish.

    The nodes reuse their message objects; a change after the publish is not sent.
    A message of more fields (JointState) is still converted at once.
    """
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from fiber_align.nodes.ros.qos import CONTROL_QOS, LATCHED_QOS
    from fiber_align.nodes.ros.sender import Sender
    pub = node.create_publisher(Float64, 'kept', LATCHED_QOS)
    s = Sender(refresh_s=0.05)
    w = s.writer(pub, False)
    assert w.field == 'data'
    assert s.writer(node.create_publisher(JointState, 'kept_js', LATCHED_QOS),
                    False).field is None
    assert s.start()
    try:
        msg = Float64(data=7.0)
        w.readers = 0
        w.publish(msg)
        msg.data = -1.0                 # the node's next sample, not published
        got = []
        node.create_subscription(Float64, 'kept', lambda m: got.append(m.data), CONTROL_QOS)
        assert _spin_until(node, lambda: got, 5.0)
        assert got[-1] == 7.0, got
    finally:
        s.stop()


def _rosout_reader(node):
    from rcl_interfaces.msg import Log
    from rclpy.qos import QoSDurabilityPolicy, QoSProfile
    got = []
    node.create_subscription(Log, '/rosout', got.append, QoSProfile(
        depth=100, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL))
    return got


def test_log_lines_go_through_the_thread_to_rosout_with_the_callers_place(node):
    """A queued line reaches /rosout with its level, the node's name and where it was written."""
    from fiber_align.nodes.ros.sender import QueuedLogger, Sender
    got = _rosout_reader(node)
    s = Sender()
    assert s.start()
    s.queue_logs(node)
    assert isinstance(node.get_logger(), QueuedLogger)
    try:
        for i in range(3):
            node.get_logger().warn('queued %d' % i)
        node.get_logger().debug('below the level: not written')
        mine = lambda: [m for m in got if m.msg.startswith('queued')]  # noqa: E731
        assert _spin_until(node, lambda: len(mine()) == 3, 10.0)
    finally:
        assert s.stop() == 0
    assert [m.msg for m in mine()] == ['queued 0', 'queued 1', 'queued 2']
    m = mine()[0]
    assert m.level == 30 and m.name == 'sender_test'
    assert m.function == ('test_log_lines_go_through_the_thread_to_rosout_with_the_callers'
                          '_place') and m.file.endswith('test_nodes_ros_sender.py')
    with open(__file__, encoding='utf-8') as f:
        src = f.read().splitlines()
    assert m.line == next(i + 1 for i, t in enumerate(src) if "warn('queued %d'" in t)
    assert s.logged == 3 and not any('below the level' in m.msg for m in got)
    node.get_logger().info('after the stop')      # the sender stopped: at once, by rclpy
    assert _spin_until(node, lambda: any(m.msg == 'after the stop' for m in got), 10.0)
    assert s.logged == 3


def test_a_log_line_that_waits_in_dds_does_not_hold_up_the_loop(node):
    """rcutils_log (console and /rosout) waiting 0.3 s on the thread: the loop runs on."""
    from fiber_align.nodes.ros.sender import Sender
    libc = ctypes.CDLL(None)
    s = Sender()
    assert s.start()
    real = s._rcl.log
    calls = []

    def slow_log(*args):
        if not calls:
            libc.usleep(300000)
        calls.append(1)
        return real(*args)
    s._rcl.log = slow_log
    s.queue_logs(node)
    try:
        t0 = time.monotonic()
        for i in range(20):
            node.get_logger().info('line %d' % i)
        took = time.monotonic() - t0
    finally:
        assert s.stop() == 0
    assert took < 0.1, took
    assert len(calls) == 20


def test_the_threads_graph_listing_is_rclpys(node):
    from std_msgs.msg import Float64, String

    from fiber_align.nodes.ros.sender import Sender
    node.create_publisher(Float64, '/listed_a', 10)
    node.create_publisher(String, '/listed_b', 10)
    sender = Sender()
    sender.watch_graph(node, 0.05)
    assert sender.start(), sender.error
    try:
        def same():
            got = sender.graph_topics()
            return got is not None and '/listed_b' in dict(got) and \
                sorted(got) == sorted(node.get_topic_names_and_types())
        assert _spin_until(node, same, 5.0), (sender.graph_topics(),
                                              node.get_topic_names_and_types())
        n = sender.graph_listings
        assert _spin_until(node, lambda: sender.graph_listings >= n + 2, 2.0)
    finally:
        sender.stop()
    assert sender.graph_topics() is None        # stopped: no listing of a node gone
