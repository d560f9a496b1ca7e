# SPDX-License-Identifier: Apache-2.0
"""``actuator_driver`` with the ``mdt693b`` backend on the MDT693B emulator (in-process)."""

import math
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import Bench
from fiber_align.graph.hardware import build_hardware
import procs
from procs import level

pytestmark = pytest.mark.ros

SUCCESS = TransitionCallbackReturn.SUCCESS
V_MAX = 90.0            # V, below the emulator's 100 V limit switch


@pytest.fixture
def rig(tmp_path):
    """Yield the driver node (hardware graph params) on an emulator, and a probe node."""
    emu = MDT693BEmulator(Bench(v_limit=100.0))
    params = build_hardware(port=emu.port, namespace='drvtest').write_params(
        str(tmp_path / 'p.yaml'))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=['--ros-args', '--params-file', params,
                                  '-p', 'diagnostics_period_s:=0.1',
                                  '-p', 'readback_period_s:=0.05'])
    from fiber_align.nodes.actuator_driver import ActuatorDriverNode
    ex = SingleThreadedExecutor(context=ctx)
    # a namespace of its own: no ghost /actuator_driver services for the graph tests
    node = ActuatorDriverNode(context=ctx, namespace='/drvtest')
    probe = rclpy.create_node('probe', context=ctx, namespace='/drvtest')
    seen = {'diag': [], 'drive': [], 'readback': []}
    probe.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: seen['diag'].extend((time.monotonic(), s) for s in m.status
                                      if s.name == '/drvtest/actuator_driver'), 50)
    probe.create_subscription(Float64, 'drive_voltage',
                              lambda m: seen['drive'].append(m.data), 1000)
    probe.create_subscription(Float64, 'drive_voltage_readback',
                              lambda m: seen['readback'].append(m.data), 100)
    ff = probe.create_publisher(Float64, 'feedforward_voltage', 1000)
    ex.add_node(node)
    ex.add_node(probe)

    def spin_until(cond, bound_s):
        return procs.spin_until(ex, cond, bound_s)

    try:
        yield emu, node, ff, seen, spin_until
    finally:
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()
        probe.destroy_node()
        rclpy.try_shutdown(context=ctx)
        emu.stop()


def test_driver_limits_ramp_unplug_and_reconnect(rig):
    emu, node, ff, seen, spin_until = rig
    assert node.get_parameter('sensorless').value is True
    # v_max above the 100 V limit switch: configure refused with the reason
    node.set_parameters([Parameter('v_max', value=120.0)])
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert spin_until(lambda: seen['diag'] and level(seen['diag'][-1][1]) == 2, 2.0)
    assert 'exceeds the device limit switch' in seen['diag'][-1][1].message
    assert not emu.command_log
    node.set_parameters([Parameter('v_max', value=V_MAX)])
    assert node.trigger_configure() == SUCCESS
    # the refusal is over: the next report is the configured state, not the latched ERROR
    node.health.publish()
    assert spin_until(lambda: level(seen['diag'][-1][1]) == 0, 1.0)
    assert node.s.dev.values()['device_limit_v'] == 100.0
    assert node.trigger_activate() == SUCCESS
    # every extreme through the topic: clamped or held by the core, checked again
    rng = np.random.default_rng(3)
    values = [math.nan, math.inf, -math.inf, 1e300, -1e300, 150.0, 100.0000001, -20.0,
              45.0] + list(rng.uniform(-1e4, 1e4, 300)) + [250.0] * 50 + [-50.0] * 50
    for v in values:
        ff.publish(Float64(data=float(v)))
        spin_until(lambda: False, 0.0005)
    ff.publish(Float64(data=30.0))
    assert spin_until(lambda: emu.command_log and emu.command_log[-1][3] == 30.0, 3.0)
    sent = [row[3] for row in emu.command_log]
    # the device link sends the newest command (which ones depends on the serial timing):
    # every input became a command, both clamps among them, and none out of range reached
    # the device
    assert {0.0, V_MAX} <= set(seen['drive'])
    assert len(seen['drive']) >= len(values) // 2
    assert all(math.isfinite(v) and 0.0 <= v <= V_MAX for v in sent)
    assert all(0.0 <= v <= V_MAX for v in seen['drive'])
    assert spin_until(lambda: seen['readback'] and abs(seen['readback'][-1] - 30.0) < 0.2,
                      2.0)
    # deactivate: the device ramps to the safe voltage (0 V) and stays there
    t0 = time.monotonic()
    assert node.trigger_deactivate() == SUCCESS
    ramp = [row for row in emu.command_log if row[0] >= t0]
    assert len(ramp) >= 5 and ramp[-1][3] == 0.0       # 30 V at 500 V/s in 5 V steps
    assert all(b[3] <= a[3] for a, b in zip(ramp, ramp[1:]))
    n = len(emu.command_log)
    spin_until(lambda: False, 0.2)
    assert len(emu.command_log) == n and node.s.dev.values('')['readback_v'] == 0.0
    # unplugged mid-run: ERROR with the reason within 1 s, then unconfigured
    assert node.trigger_activate() == SUCCESS
    ff.publish(Float64(data=20.0))
    assert spin_until(lambda: emu.command_log[-1][3] == 20.0, 2.0)
    t_unplug = time.monotonic()
    emu.unplug()
    for _ in range(5):
        ff.publish(Float64(data=21.0))
        spin_until(lambda: False, 0.01)
    assert spin_until(lambda: node.s is None and any(
        level(s) == 2 and 'device lost' in s.message and t > t_unplug
        for t, s in seen['diag']), 2.0)
    t_err, st = [(t, s) for t, s in seen['diag'] if level(s) == 2 and t > t_unplug][0]
    assert t_err - t_unplug < 1.0
    assert st.message.startswith('device lost: MDT693B: ')
    assert '\n' not in st.message and 'Traceback' not in st.message
    assert node._state_machine.current_state[1] == 'unconfigured'
    assert node.trigger_configure() == TransitionCallbackReturn.FAILURE   # still gone
    # re-plugged (the same link): a configure reconnects
    emu.plug()
    assert node.trigger_configure() == SUCCESS
    assert node.trigger_activate() == SUCCESS
    ff.publish(Float64(data=12.5))
    assert spin_until(lambda: emu.command_log[-1][3] == 12.5, 2.0)
    assert node.trigger_deactivate() == SUCCESS
    assert node.trigger_cleanup() == SUCCESS
