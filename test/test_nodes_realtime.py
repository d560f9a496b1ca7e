# SPDX-License-Identifier: Apache-2.0
"""Realtime graph as separate processes, driven by an outside rclpy client.

One sequence (to keep the ROS test set short): the client publishes a 50 um setpoint
and the actuator settles there; NaN, inf and out-of-range setpoints are rejected with a
diagnostics WARN and the actuator stays; killing the controller makes the driver's
watchdog ramp the drive to 0 V; a restarted controller brings the actuator back.
"""

import os
import signal
import subprocess
import sys
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODES = ('simulated_actuator', 'hysteresis_compensator', 'fuzzy_pid_controller',
         'actuator_driver')


def spawn(name):
    """Start one node process."""
    return subprocess.Popen([sys.executable, '-m', 'fiber_align.nodes.' + name],
                            env=dict(os.environ), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def stop(proc):
    """SIGINT, then SIGKILL after 5 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@pytest.mark.xfail(reason='realtime loop limit-cycles on the loaded 2-core machine; '
                   'see docs/ros_interface.md (open issue)', strict=False)
def test_outside_client_setpoint_watchdog_recovery():
    """Setpoint tracking, bad-setpoint rejection, watchdog ramp and recovery."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from lifecycle_msgs.srv import ChangeState
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    procs = {n: spawn(n) for n in NODES}
    rclpy.init()
    node = rclpy.create_node('outside_client')
    try:
        ys, drives, warns = [], [], []
        node.create_subscription(JointState, 'displacement',
                                 lambda m: ys.append(m.position[0]), 100)
        node.create_subscription(Float64, 'drive_voltage', lambda m: drives.append(
            (time.monotonic(), m.data)), 100)
        node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: warns.extend(
            s.message for s in m.status if s.level == b'\x01' and 'rejected' in s.message),
            100)
        pub = node.create_publisher(Float64, 'setpoint', 10)

        def spin_for(seconds, until=None):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.01)
                if until is not None and until():
                    return True
            return False

        cli = node.create_client(ChangeState, 'actuator_driver/change_state')
        assert cli.wait_for_service(timeout_sec=30)
        for tid in (1, 3):
            req = ChangeState.Request()
            req.transition.id = tid
            fut = cli.call_async(req)
            rclpy.spin_until_future_complete(node, fut, timeout_sec=10)
            assert fut.done() and fut.result().success
        assert spin_for(20, lambda: pub.get_subscription_count() >= 2 and len(ys) > 10)

        # 1. move to 50 um and settle
        pub.publish(Float64(data=50e-6))
        spin_for(4.0)
        tail = ys[-200:]
        assert abs(sum(tail) / len(tail) - 50e-6) < 1.0e-6, tail[-5:]

        # 2. bad setpoints: rejected with a WARN, the actuator stays
        for bad in (float('nan'), float('inf'), 1.0):
            pub.publish(Float64(data=bad))
        assert spin_for(5.0, lambda: len(warns) >= 3), warns
        spin_for(0.5)
        tail = ys[-200:]
        assert abs(sum(tail) / len(tail) - 50e-6) < 1.0e-6

        # 3. kill the controller: the watchdog (0.05 s) ramps the drive to 0 V
        procs['fuzzy_pid_controller'].kill()
        procs['fuzzy_pid_controller'].wait(timeout=5)
        t_kill = time.monotonic()
        assert spin_for(5.0, lambda: drives and drives[-1][1] == 0.0
                        and drives[-1][0] > t_kill)
        assert drives[-1][0] - t_kill < 1.0   # timeout 0.05 s + ramp, generous bound

        # 4. restart: the controller recovers the setpoint (latest is kept by the client)
        procs['fuzzy_pid_controller'] = spawn('fuzzy_pid_controller')
        assert spin_for(20, lambda: pub.get_subscription_count() >= 2)
        for _ in range(6):    # a late-joining controller gets the setpoint on a re-send
            pub.publish(Float64(data=50e-6))
            spin_for(0.5)
        tail = ys[-200:]
        assert abs(sum(tail) / len(tail) - 50e-6) < 1.0e-6
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        for p in procs.values():
            stop(p)
