# SPDX-License-Identifier: Apache-2.0
"""
A foreign publisher on the hardware bench's drive input holds the MDT693B (issue 39.1).

The sensorless 1-D bench on the emulators, TRACKING: a node of another name publishes
100 V on ``feedforward_voltage`` at 1 kHz for 5 s. The driver holds its output where it
is (no command of the amplifier moves the fiber), and its ``/diagnostics`` ERROR names
the publisher; the fiber stays on the slot.
"""

import time

import pytest

INTRUDER = 'intruder_graph_b'


@pytest.mark.ros  # starts processes
def test_a_foreign_feedforward_publisher_holds_the_amplifier_and_is_named():
    import rclpy
    from std_msgs.msg import Float64

    from fiber_align.bringup.hardware import HardwareRun
    from fiber_align.graph.hardware import build_hardware
    from fiber_align.hardware.bench import emulated
    from fiber_align.nodes.ros.qos import LIVE_QOS
    with emulated(seed=3, slot_position_m=40e-6) as (bench, mdt, pm):
        hw = HardwareRun(build_hardware(port=mdt.port, visa_resource=pm.resource))
        try:
            hw.start()
            ok, _ = hw.align()
            assert ok, hw.status
            time.sleep(0.3)
            ch = bench.fiber_channel
            v_before, loss_before = bench.output_v(ch), bench.true_loss_db()
            n = len(mdt.command_log)
            node = rclpy.create_node(INTRUDER, context=hw.obs.ctx)
            pub = node.create_publisher(Float64, 'feedforward_voltage', LIVE_QOS)
            t0, k, worst = time.monotonic(), 0, 0.0
            try:
                while time.monotonic() - t0 < 5.0:
                    pub.publish(Float64(data=100.0))
                    k += 1
                    if k % 50 == 0:     # the amplifier's output, every 50 ms
                        worst = max(worst, abs(bench.output_v(ch) - v_before))
                    time.sleep(max(0.0, t0 + k / 1000.0 - time.monotonic()))
            finally:
                node.destroy_node()
            level, msg = hw.diag.get(hw.driver, (None, ''))
            volts = [row[3] for row in mdt.command_log[n:] if row[1] == ch]
            print('%d foreign messages; output moved at most %.3f V from %.2f V; commands '
                  'sent %s; %s: %s' % (k, worst, v_before, sorted(set(volts))[:4], level, msg))
            assert k > 500
            assert level == 2 and INTRUDER in msg, (level, msg)
            # held: no command after the intrusion's start went above the tracked voltage
            # by more than the dither's swing; never toward the 100 V sent
            assert all(v < v_before + 1.0 for v in volts), sorted(set(volts))[-4:]
            assert worst < 1.0, worst
            assert bench.true_loss_db() < loss_before + 0.5
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes
