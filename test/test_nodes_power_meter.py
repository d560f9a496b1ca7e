# SPDX-License-Identifier: Apache-2.0
"""The ``power_meter`` node on the PM100 emulator: readings, rate, loss and recovery."""

import time

from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64

from fiber_align.hardware.emulators.physics import Bench
from fiber_align.hardware.emulators.pm100 import PM100Emulator
import procs
from procs import level

pytestmark = pytest.mark.ros


def test_power_meter_node_reads_survives_a_lost_meter_and_recovers():
    emu = PM100Emulator(Bench(slot_position_m=0.0, seed=3))
    ctx = rclpy.Context()          # its own context: other tests' rclpy state is untouched
    rclpy.init(context=ctx, args=[
        '--ros-args', '-p', 'resource:=%s' % emu.resource, '-p', 'rate_hz:=100.0', '-p',
        'reconnect_period_s:=0.2', '-p', 'diagnostics_period_s:=0.1'])
    from fiber_align.nodes.power_meter import PowerMeterNode
    node = probe = None
    ex = SingleThreadedExecutor(context=ctx)
    try:
        node = PowerMeterNode(context=ctx)
        probe = rclpy.create_node('probe', context=ctx)
        got, diags = [], []
        probe.create_subscription(Float64, 'optical_power', lambda m: got.append(m.data), 10)
        probe.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: diags.extend((time.monotonic(), s) for s in m.status
                                   if s.name == '/power_meter'), 10)
        ex.add_node(node)
        ex.add_node(probe)

        def spin_until(cond, bound_s):
            return procs.spin_until(ex, cond, bound_s, 0.02)

        def rate(s):
            return float({kv.key: kv.value for kv in s.values}['rate_hz'])

        # fiber tip at 0 um, slot at 0 um: light; readings at about 100 Hz
        assert spin_until(lambda: len(got) >= 100 and diags and level(diags[-1][1]) == 0
                          and rate(diags[-1][1]) > 50.0, 10.0)
        assert all(p > 0.5e-3 for p in got[-20:])          # W, about 1 mW coupled
        assert 50.0 < rate(diags[-1][1]) <= 110.0
        t_unplug = time.monotonic()
        emu.unplug()
        assert spin_until(lambda: level(diags[-1][1]) == 2, 3.0)
        t_err, st = [(t, s) for t, s in diags if level(s) == 2 and t > t_unplug][0]
        assert t_err - t_unplug < 1.0
        assert st.message.startswith('PM100: ')
        emu.plug()
        n = len(got)
        assert spin_until(lambda: level(diags[-1][1]) == 0 and len(got) > n + 20, 5.0)
    finally:
        ex.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        if probe is not None:
            probe.destroy_node()
        rclpy.try_shutdown(context=ctx)
        emu.stop()
