# SPDX-License-Identifier: Apache-2.0
"""
The Foxglove live view on a running realtime graph (``bringup --live``).

The client here is written from the Foxglove WebSocket protocol specification on the
``websockets`` package (no Foxglove code): the ``foxglove.sdk.v1`` subprotocol (the only
one the SDK's server accepts: it refuses ``foxglove.websocket.v1`` with HTTP 400), JSON
text frames for ``serverInfo``, ``advertise``, ``subscribe`` and ``status``, binary
``messageData`` frames (opcode 1, subscription id u32, log time u64, payload).

One graph (the 1-D realtime graph waiting for setpoints, the view on a free port) serves
the tests in file order: the channel list holds every topic the graph's nodes publish
and every topic of the shipped layout; ``displacement`` delivers at least 50 messages in
2 s while the test moves the setpoint, whose CDR positions are the ones an rclpy
subscriber saw at the same stamps (within 1 um); garbage and unknown channels are
refused to that client only (a status message) and the view serves on; a second view
on the same port, and ``bringup --live`` on it, refuse with one line. Then the rig (its
processes from the description, as the launch file starts them, lockstep, with the
view): after
``align`` the power map's brightest cell lies within 1 um of the aligned point the
sequencer reports. Every wait is bounded; every process is stopped by its pid.
"""

import asyncio
import base64
import json
import math
import os
from pathlib import Path
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from fiber_align.analysis import liveview as lv
from fiber_align.analysis import powermap
from fiber_align.graph import description as gd
from fiber_align.graph.live import graph_published, with_live
from procs import stop, wait_log

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
PROTOCOL = 'foxglove.sdk.v1'
BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']
UM = 1e-6


def free_port():
    """Return a TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    """Yield ``(port, proc, log)``: ``bringup --live`` running (scenario none)."""
    port = free_port()
    log = tmp_path_factory.mktemp('live') / 'bringup.log'
    with open(log, 'wb') as f:
        proc = subprocess.Popen(BRINGUP + ['--live', '--live-port', str(port)],
                                env=dict(os.environ), stdout=f, stderr=subprocess.STDOUT)
    try:
        assert wait_log(log, 'running; publish', 90.0, proc), log.read_text()[-4000:]
        yield port, proc, log
    finally:
        stop(proc)


class Client:
    """A Foxglove WebSocket client (the protocol's JSON and binary frames)."""

    def __init__(self, ws):
        """Wrap an open ``websockets`` connection."""
        self.ws = ws
        self.channels = {}          # topic -> advertised channel
        self.status = []
        self.data = []              # (subscription id, log time ns, payload, t received)
        self.info = None

    async def pump(self, seconds, until=None):
        """Read frames for at most ``seconds`` (s) or until ``until()``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (until and until()):
            try:
                frame = await asyncio.wait_for(self.ws.recv(), end - time.monotonic())
            except asyncio.TimeoutError:
                break
            if isinstance(frame, bytes):
                if frame[0] == 1:
                    sub, t_ns = struct.unpack_from('<IQ', frame, 1)
                    self.data.append((sub, t_ns, frame[13:], time.monotonic()))
                continue
            msg = json.loads(frame)
            if msg['op'] == 'serverInfo':
                self.info = msg
            elif msg['op'] == 'advertise':
                self.channels.update({c['topic']: c for c in msg['channels']})
            elif msg['op'] == 'unadvertise':
                gone = set(msg['channelIds'])
                self.channels = {t: c for t, c in self.channels.items() if c['id'] not in gone}
            elif msg['op'] == 'status':
                self.status.append(msg)

    async def subscribe(self, sub_id, topic):
        """Subscribe ``sub_id`` to the channel of ``topic``."""
        await self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': sub_id, 'channelId': self.channels[topic]['id']}]}))


def expected_topics():
    """Return the absolute topics the graph's nodes publish (the description's)."""
    return {'/' + t for t in graph_published(with_live(gd.build(), True))}


def run(coro):
    """Run a coroutine in a new loop (each test its own)."""
    return asyncio.run(coro)


async def _connect(port):
    import websockets
    return await websockets.connect('ws://127.0.0.1:%d' % port, subprotocols=[PROTOCOL],
                                    max_size=None, open_timeout=10)


def test_channels_hold_every_published_topic_and_every_layout_topic(graph):
    port, proc, log = graph
    want = expected_topics()
    layout = json.loads((ROOT / 'layouts' / 'fiber_align.json').read_text())
    need = want | lv.layout_topics(layout)

    async def go():
        ws = await _connect(port)
        try:
            assert ws.subprotocol == PROTOCOL
            c = Client(ws)
            await c.pump(15.0, lambda: need <= set(c.channels))
            return c
        finally:
            await ws.close()
    c = run(go())
    assert c.info is not None and c.info['op'] == 'serverInfo'
    assert want <= set(c.channels), sorted(want - set(c.channels))
    assert lv.layout_topics(layout) <= set(c.channels), \
        sorted(lv.layout_topics(layout) - set(c.channels))
    d = c.channels['/displacement']
    assert (d['encoding'], d['schemaEncoding'], d['schemaName']) == (
        'cdr', 'ros2msg', 'sensor_msgs/msg/JointState')
    assert 'MSG: std_msgs/Header' in d['schema'] and 'float64[] position' in d['schema']
    assert '100 Hz' in d['metadata']['decimation']
    assert proc.poll() is None


def test_displacement_matches_an_rclpy_subscriber_within_1_um(graph):
    port, proc, log = graph
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    seen = {}
    rclpy.init()
    node = rclpy.create_node('live_view_test')
    try:
        node.create_subscription(
            JointState, 'displacement',
            lambda m: seen.__setitem__(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                       m.position[0]),
            QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
        pub = node.create_publisher(Float64, 'setpoint', 10)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        stop_spin = threading.Event()

        def spin():
            while not stop_spin.is_set():
                ex.spin_once(timeout_sec=0.01)
        th = threading.Thread(target=spin, daemon=True)
        th.start()
        try:
            end = time.monotonic() + 10.0
            while time.monotonic() < end and not pub.get_subscription_count():
                time.sleep(0.05)
            # the graph drives before the window: a setpoint reaches the tip (the view's
            # frames are compared with the rclpy side's, not with the graph's start-up)
            end = time.monotonic() + 30.0
            while time.monotonic() < end and not any(
                    abs(y - 40 * UM) < 2 * UM for y in list(seen.values())[-20:]):
                pub.publish(Float64(data=40 * UM))
                time.sleep(0.2)
            assert any(abs(y - 40 * UM) < 2 * UM for y in list(seen.values())[-20:]), (
                'the graph does not reach a 40 um setpoint: %s' % log.read_text()[-3000:])

            async def go():
                ws = await _connect(port)
                try:
                    c = Client(ws)
                    await c.pump(10.0, lambda: '/displacement' in c.channels)
                    await c.subscribe(7, '/displacement')
                    c.data.clear()
                    t0 = time.monotonic()
                    # move the tip during the window: 20 um, then 60 um
                    pub.publish(Float64(data=20 * UM))
                    await c.pump(1.0)
                    pub.publish(Float64(data=60 * UM))
                    await c.pump(2.0 - (time.monotonic() - t0))
                    return c
                finally:
                    await ws.close()
            c = run(go())
            time.sleep(0.3)                 # the rclpy side takes the last ones
        finally:
            stop_spin.set()
            th.join(2.0)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    got = [(lv.joint_state(p)[0], lv.joint_state(p)[1][0]) for s, _, p, _ in c.data if s == 7]
    assert len(got) >= 50, len(got)
    positions = [y for _, y in got]
    assert max(positions) - min(positions) > 20 * UM     # the tip moved in the window
    matched = [(y, seen[t]) for t, y in got if t in seen]
    # the rclpy side spins in this loaded test process and may miss a part of them
    assert len(matched) >= max(30, 0.6 * len(got)), (len(matched), len(got))
    assert max(abs(a - b) for a, b in matched) <= 1 * UM
    assert proc.poll() is None


def test_a_per_sample_topic_is_read_only_while_a_client_watches_it(graph):
    """The view's DDS reader of ``feedback_voltage`` exists only while a client subscribes."""
    port, proc, log = graph
    import rclpy
    rclpy.init()
    node = rclpy.create_node('live_view_lazy_test')

    def view_readers():
        return sum(i.node_name == 'live_view_taps'
                   for i in node.get_subscriptions_info_by_topic('/feedback_voltage'))

    def until(want, seconds=5.0):
        end = time.monotonic() + seconds
        while view_readers() != want and time.monotonic() < end:
            time.sleep(0.05)
        return view_readers()
    try:
        async def go():
            ws = await _connect(port)
            try:
                c = Client(ws)
                await c.pump(15.0, lambda: '/feedback_voltage' in c.channels)
                seen = [until(0)]                           # advertised, nobody watching
                await c.subscribe(3, '/feedback_voltage')
                seen.append(await asyncio.to_thread(until, 1))
                await c.pump(1.0)
                seen.append(sum(s == 3 for s, *_ in c.data))
                await ws.send(json.dumps({'op': 'unsubscribe', 'subscriptionIds': [3]}))
                seen.append(await asyncio.to_thread(until, 0))
                return seen
            finally:
                await ws.close()
        before, during, frames, after = run(go())
    finally:
        node.destroy_node()
        rclpy.shutdown()
    assert (before, during, after) == (0, 1, 0)
    assert frames >= 10                  # the reader made on subscribe delivers (100 Hz)
    assert proc.poll() is None


def test_garbage_and_unknown_channels_are_refused_to_that_client_only(graph):
    port, proc, log = graph

    async def go():
        vanished = await _connect(port)
        await vanished.send('{"op": "subscribe", "subscriptions": [{"id": 1, "chann')
        vanished.transport.abort()          # gone without a close frame
        ws = await _connect(port)
        try:
            c = Client(ws)
            await c.pump(10.0, lambda: '/displacement' in c.channels)
            await ws.send('not json at all')
            await ws.send(b'\xff\x00garbage')
            await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                {'id': 3, 'channelId': 987654}]}))
            await ws.send(json.dumps({'op': 'no such op'}))
            await c.subscribe(4, '/drive_voltage')
            await c.pump(2.0)
            return c
        finally:
            await ws.close()
    c = run(go())
    assert len(c.status) >= 2, c.status
    assert any('987654' in s['message'] for s in c.status), c.status
    assert sum(1 for s, *_ in c.data if s == 4) >= 50     # it serves on
    assert proc.poll() is None


def test_a_second_view_on_the_port_refuses_with_one_line(graph):
    port, proc, log = graph
    out = subprocess.run(
        [sys.executable, '-m', 'fiber_align.nodes.live_view', '--ros-args', '-r',
         '__node:=live_view_2', '-p', 'port:=%d' % port], env=dict(os.environ),
        capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stdout + out.stderr
    lines = [ln for ln in out.stderr.splitlines() if 'cannot serve' in ln]
    assert len(lines) == 1 and 'Address already in use' in lines[0], out.stderr
    out = subprocess.run(BRINGUP + ['--live', '--live-port', str(port)],
                         env=dict(os.environ), capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and 'live view ws://127.0.0.1:%d' % port in out.stderr, \
        out.stdout + out.stderr
    assert 'started' not in out.stdout          # refused before any process
    out = subprocess.run(BRINGUP + ['--live', '--live-host', 'bad host'],
                         env=dict(os.environ), capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "live_host 'bad host'" in out.stderr, out.stderr
    assert proc.poll() is None


def test_rig_power_map_peaks_within_1_um_of_the_aligned_point(tmp_path):
    """The rig as the launch file starts it (its processes from the description), lockstep."""
    import rclpy
    from std_srvs.srv import Trigger

    from fiber_align.graph import rig as gr
    from fiber_align.graph.description import dds_environment
    port = free_port()
    # namespace rig, as the layout; lockstep: a loaded machine cannot fault the rig's
    # realtime loop in the middle of the test (the view's side is the same)
    g = with_live(gr.build_rig(sync_mode='lockstep'), True, port)
    params = g.write_params(str(tmp_path / 'params.yaml'))
    env = dds_environment(dict(os.environ))
    procs = []
    rclpy.init()
    node = rclpy.create_node('live_view_rig_test')
    try:
        for p in g.processes:
            with open(tmp_path / (p.name.replace('/', '_') + '.log'), 'wb') as f:
                procs.append(subprocess.Popen(
                    p.command(params, g.namespace, g.remappings, sys.executable), env=env,
                    stdout=f, stderr=subprocess.STDOUT))
        align = node.create_client(Trigger, '/rig/align')

        async def go():
            ws = None
            end = time.monotonic() + 60.0
            while ws is None and time.monotonic() < end:
                try:
                    ws = await _connect(port)
                except OSError:
                    await asyncio.sleep(0.3)
            assert ws is not None, 'no live view on port %d' % port
            try:
                c = Client(ws)
                layout = json.loads((ROOT / 'layouts' / 'fiber_align_rig.json').read_text())
                want = lv.layout_topics(layout)
                assert '/rig/live_view/power_map' in want
                await c.pump(60.0, lambda: want <= set(c.channels))
                # the rig's layout names only channels the view advertises
                assert want <= set(c.channels), sorted(want - set(c.channels))
                await c.subscribe(1, '/rig/live_view/power_map')
                await c.subscribe(2, '/rig/live_view/alignment')
                # the drivers active and the plants running: the x displacement flows
                await c.subscribe(3, '/rig/x/displacement')
                await c.pump(60.0, lambda: any(s == 3 for s, *_ in c.data))
                assert align.wait_for_service(timeout_sec=30.0)
                # the sequencer refuses while a driver is not active yet (lifecycle_manager
                # activates them one after the other): ask again, as a user would
                end = time.monotonic() + 30.0
                while True:
                    future = align.call_async(Trigger.Request())
                    rclpy.spin_until_future_complete(node, future, timeout_sec=20.0)
                    res = future.result()
                    if res is None or res.success or 'not active' not in res.message \
                            or time.monotonic() > end:
                        break
                    await asyncio.sleep(0.5)
                assert res is not None and res.success, res

                def tracking():
                    return any(s == 2 and json.loads(p).get('state') == 'TRACKING'
                               for s, _, p, _ in c.data)
                await c.pump(30.0, tracking)
                assert tracking(), [json.loads(p) for s, _, p, _ in c.data if s == 2][-3:]
                # a map made well into TRACKING: its brightest cells are the dither's
                # readings at the peak, not one of the search's (a pass crosses the peak
                # at 3 um a sample, and the view's readers of x, y and the power are
                # three DDS readers: a reading may be paired with a neighbouring sample)
                await c.pump(2.0, lambda: False)
                n = len(c.data)
                await c.pump(5.0, lambda: any(s == 1 for s, *_ in c.data[n:]))
                return c, n
            finally:
                await ws.close()
        c, n = run(go())
    finally:
        for proc in procs:
            stop(proc)
        node.destroy_node()
        rclpy.shutdown()
    states = [json.loads(p) for s, _, p, _ in c.data if s == 2]
    aligned = [s for s in states if s.get('state') == 'TRACKING'][-1]
    grid = json.loads([p for s, _, p, _ in c.data[n:] if s == 1][-1])
    x, y, peak_dbm = powermap.grid_peak(grid)
    assert math.hypot(x - aligned['aligned_x_m'], y - aligned['aligned_y_m']) <= 1 * UM, (
        (x, y), (aligned['aligned_x_m'], aligned['aligned_y_m']))
    assert peak_dbm > -30.0                 # light at the peak
    cells = np.frombuffer(base64.b64decode(grid['data']), dtype='<f4')
    # more than the peak is on the map: the search's path (tens of cells on a quiet
    # machine; the view's best-effort readers lose samples when it is starved)
    assert np.isfinite(cells).sum() >= 3, np.isfinite(cells).sum()
