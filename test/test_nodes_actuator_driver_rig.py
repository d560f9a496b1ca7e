# SPDX-License-Identifier: Apache-2.0
"""``actuator_driver`` as the rig's ``mdt693b_driver``: one MDT693B, both axes (in-process)."""

import time

from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import TransitionCallbackReturn
from std_msgs.msg import Bool, Float64
import yaml

from fiber_align.config import ConfigError, dump_params
from fiber_align.graph.hardware_rig import build_hardware_rig
from fiber_align.graph.params import GraphError
from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import RigBench
import procs
from procs import level

pytestmark = pytest.mark.ros

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
NS = 'rigdrv'
FQN = '/%s/mdt693b_driver' % NS


class Rig:
    """The driver node on an emulated MDT693B, and a probe node publishing both inputs."""

    def __init__(self, tmp_path, over=None, model='MDT693B'):
        """Start the emulator, the node (hardware rig params, ``over`` its own), the probe."""
        self.emu = MDT693BEmulator(RigBench(v_limit=100.0), model=model, baud=115200,
                                   turnaround_s=1e-3)
        path = build_hardware_rig(port=self.emu.port, namespace=NS).write_params(
            str(tmp_path / 'p.yaml'))
        # the node's own values written into its section (a -p would lose to it); not
        # through the graph, which refuses some of them itself
        data = yaml.safe_load(open(path, encoding='utf-8'))
        mine = data[FQN]['ros__parameters']
        for k, v in (over or {}).items():
            axis, _, key = k.rpartition('.')
            (mine[axis] if axis else mine)[key] = v
        mine['diagnostics_period_s'] = 0.1
        with open(path, 'w', encoding='utf-8') as f:
            dump_params(data, f)
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, args=['--ros-args', '--params-file', path])
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.node = None
        self.probe = rclpy.create_node('probe', context=self.ctx, namespace='/' + NS)
        self.diag = []
        self.held = {'x': [], 'y': []}
        self.probe.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: self.diag.extend((time.monotonic(), s) for s in m.status
                                       if s.name.startswith(FQN)), 100)
        for a in 'xy':
            self.probe.create_subscription(Bool, a + '/drive_held',
                                           lambda m, a=a: self.held[a].append(m.data), 10)
        self.ff = {a: self.probe.create_publisher(Float64, a + '/feedforward_voltage', 100)
                   for a in 'xy'}
        self.ex.add_node(self.probe)

    def make(self):
        """Build the driver node (raises what its constructor raises)."""
        from fiber_align.nodes.actuator_driver import ActuatorDriverNode
        self.node = ActuatorDriverNode(context=self.ctx, namespace='/' + NS,
                                       node_name='mdt693b_driver')
        self.ex.add_node(self.node)
        return self.node

    def spin_until(self, cond, bound_s):
        return procs.spin_until(self.ex, cond, bound_s)

    def spin(self, seconds):
        self.spin_until(lambda: False, seconds)

    def status(self, name=FQN):
        for _, st in reversed(self.diag):
            if st.name == name:
                return st
        return None

    def feed(self, seconds, vx, vy, period_s=0.01, axes='xy'):
        """Publish the feedforwards (V) every period for ``seconds`` (s)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for a, v in (('x', vx), ('y', vy)):
                if a in axes:
                    self.ff[a].publish(Float64(data=float(v)))
            self.spin_until(lambda: False, period_s)

    def close(self):
        self.ex.shutdown(timeout_sec=1.0)
        if self.node is not None:
            self.node.destroy_node()
        self.probe.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        self.emu.stop()


@pytest.fixture
def make_rig(tmp_path):
    made = []

    def make(model='MDT693B', **over):
        made.append(Rig(tmp_path, over, model))
        return made[-1]
    try:
        yield make
    finally:
        for r in made:
            r.close()


def channel_values(emu, ch, t0=0.0):
    return [v for t, c, _, v in list(emu.command_log) if c == ch and t >= t0]


@pytest.mark.parametrize('combined', ['true', 'false'])
def test_both_axes_reach_their_channels_in_order(make_rig, combined):
    # x on the amplifier's y channel and y on z: which channel is which axis is a parameter
    r = make_rig(combined_write=combined == 'true', **{'x.channel': 'y', 'y.channel': 'z'})
    node = r.make()
    assert node.trigger_configure() == SUCCESS
    assert node.trigger_activate() == SUCCESS
    t0 = time.monotonic()
    sent_x = [10.0 + i for i in range(12)]
    sent_y = [50.0 - 2 * i for i in range(12)]
    for vx, vy in zip(sent_x, sent_y):
        # slower than the driver's slew and the link: each value is its own command
        r.feed(0.03, vx, vy, period_s=0.015)
    assert r.spin_until(lambda: channel_values(r.emu, 'z', t0)[-1:] == [sent_y[-1]], 2.0)
    got_x = channel_values(r.emu, 'y', t0)
    got_y = channel_values(r.emu, 'z', t0)
    # each axis's values reach its channel, in the order published, nothing else there
    dedup = [v for i, v in enumerate(got_x) if i == 0 or v != got_x[i - 1]]
    assert dedup == sent_x, got_x
    dedup = [v for i, v in enumerate(got_y) if i == 0 or v != got_y[i - 1]]
    assert dedup == sent_y, got_y
    log = [row for row in r.emu.command_log if row[0] >= t0]
    assert all(row[1] in ('y', 'z') or row[3] == 0.0 for row in log), log[:5]
    if combined == 'true':
        assert all(row[2].startswith('xyzvoltage=') for row in log)
    else:
        assert all(not row[2].startswith('xyzvoltage=') for row in log)
    # the device's status: port, limit switch, id?, rate
    assert r.spin_until(lambda: r.status() is not None and 'command_rate_hz' in {
        kv.key for kv in r.status().values}, 3.0)
    vals = {kv.key: kv.value for kv in r.status().values}
    assert vals['port'] == r.emu.port and float(vals['device_limit_v']) == 100.0
    assert 'MDT693B' in vals['device'] and float(vals['command_rate_hz']) > 0
    for a, ch in (('x', 'y'), ('y', 'z')):
        st = r.status('%s/%s' % (FQN, a))
        assert st is not None and {kv.key: kv.value for kv in st.values}['channel'] == ch
    # deactivate: both axes ramped to 0 V, in falling steps, and nothing follows
    t1 = time.monotonic()
    assert node.trigger_deactivate() == SUCCESS
    for ch in 'yz':
        ramp = channel_values(r.emu, ch, t1)
        assert ramp[-1] == 0.0 and all(b <= a for a, b in zip(ramp, ramp[1:])), ramp
    n = len(r.emu.command_log)
    r.spin(0.2)
    assert len(r.emu.command_log) == n
    assert r.held['x'][-1] is True and r.held['y'][-1] is True


def test_one_axis_silent_holds_both(make_rig):
    r = make_rig()
    node = r.make()
    assert node.trigger_configure() == SUCCESS and node.trigger_activate() == SUCCESS
    r.feed(0.5, 30.0, 40.0)
    assert r.spin_until(lambda: abs(r.emu.bench.output_v('x') - 30.0) < 0.5, 1.0)
    # y stops, x goes on: the y watchdog trips and x ramps to its safe voltage too
    t0 = time.monotonic()
    r.feed(1.0, 30.0, 0.0, axes='x')
    assert r.emu.bench.output_v('x') < 0.5 and r.emu.bench.output_v('y') < 0.5
    assert r.held['x'][-1] is True and r.held['y'][-1] is True
    msgs = [st.message for t, st in r.diag if t >= t0 and level(st) == 2]
    assert any(m.startswith('watchdog: axis y:') for m in msgs), msgs
    # y is back: both axes follow again
    r.feed(1.0, 30.0, 40.0)
    assert abs(r.emu.bench.output_v('x') - 30.0) < 0.5
    assert abs(r.emu.bench.output_v('y') - 40.0) < 0.5


def test_both_axes_silent_then_back_follow_again(make_rig):
    # a stall upstream of both axes (the meter, the sequencer) trips both watchdogs in
    # one tick; each axis then holds while the other is tripped, which must not hold
    # either for ever once both inputs are back
    r = make_rig()
    node = r.make()
    assert node.trigger_configure() == SUCCESS and node.trigger_activate() == SUCCESS
    r.feed(0.5, 30.0, 40.0)
    assert r.spin_until(lambda: abs(r.emu.bench.output_v('y') - 40.0) < 0.5, 1.0)
    r.spin(1.0)
    assert r.held['x'][-1] is True and r.held['y'][-1] is True
    assert r.emu.bench.output_v('x') < 0.5 and r.emu.bench.output_v('y') < 0.5
    r.feed(1.0, 30.0, 40.0)
    assert r.held['x'][-1] is False and r.held['y'][-1] is False
    assert abs(r.emu.bench.output_v('x') - 30.0) < 0.5
    assert abs(r.emu.bench.output_v('y') - 40.0) < 0.5


@pytest.mark.parametrize('over, model, why', [
    ({'y.v_max': 120.0}, 'MDT693B',
     'MDT693B: limit: axis y: v_max 120 V exceeds the device limit switch setting 100 V'),
    ({'x.v_max': 150.0}, 'MDT693B',
     'MDT693B: limit: axis x: v_max 150 V exceeds the device limit switch setting 100 V'),
    ({}, 'MDT694B', 'MDT693B: limit: axis y: channel y does not exist on Model MDT694B'),
])
def test_configure_refuses_what_the_unit_cannot_take(make_rig, over, model, why):
    r = make_rig(model=model, **over)
    node = r.make()
    assert node.trigger_configure() == FAILURE
    assert r.spin_until(lambda: r.status() is not None and level(r.status()) == 2, 2.0)
    assert r.status().message.startswith(why), r.status().message
    assert '\n' not in r.status().message
    assert not r.emu.command_log                   # nothing was sent


def test_a_channel_named_twice_is_refused_in_one_line(make_rig):
    with pytest.raises(GraphError) as exc:
        build_hardware_rig(port='/dev/null', overrides={'mdt693b_driver': {'y.channel': 'x'}})
    assert str(exc.value) == ('channel x is named twice (mdt693b_driver.x.channel and '
                              'y.channel)')
    r = make_rig(**{'y.channel': 'x'})
    with pytest.raises(ConfigError) as exc:
        r.make()
    assert str(exc.value) == 'mdt693b_driver: channel x is named twice (axes x and y)'
    assert not r.emu.command_log


def test_unplug_mid_run_error_within_1s_and_recover(make_rig):
    r = make_rig()
    node = r.make()
    assert node.trigger_configure() == SUCCESS and node.trigger_activate() == SUCCESS
    r.feed(0.4, 30.0, 40.0)
    t0 = time.monotonic()
    r.emu.unplug()
    r.feed(1.0, 30.0, 40.0)
    errs = [(t, st) for t, st in r.diag if st.name == FQN and level(st) == 2 and t >= t0]
    assert errs and errs[0][0] - t0 < 1.0
    assert errs[0][1].message.startswith('device lost: MDT693B: ')
    assert '\n' not in errs[0][1].message
    assert node._state_machine.current_state[1] == 'unconfigured'
    assert r.held['x'][-1] is True and r.held['y'][-1] is True
    # configure refused while unplugged, one line
    assert node.trigger_configure() == FAILURE
    # re-plugged: the lifecycle reconnects and ramps both axes to their safe voltage
    r.emu.plug()
    t1 = time.monotonic()
    assert node.trigger_configure() == SUCCESS
    assert r.emu.bench.output_v('x') < 0.5 and r.emu.bench.output_v('y') < 0.5
    ramp = channel_values(r.emu, 'x', t1)
    assert ramp and ramp[-1] == 0.0 and all(b <= a for a, b in zip(ramp, ramp[1:]))
    assert node.trigger_activate() == SUCCESS
    r.feed(0.5, 20.0, 25.0)
    assert abs(r.emu.bench.output_v('x') - 20.0) < 0.5
    assert abs(r.emu.bench.output_v('y') - 25.0) < 0.5
