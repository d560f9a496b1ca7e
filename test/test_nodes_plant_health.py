# SPDX-License-Identifier: Apache-2.0
"""
The plant's cycle health after five driver deactivate/activate cycles (issue 39.7).

A realtime graph (``bringup --scenario sine``, 1 kHz) runs while this test deactivates
and activates ``actuator_driver`` five times through its ``change_state`` service (1 s
inactive, 1 s active each), then leaves it active for 11 s. The plant's ``/diagnostics``
then: the periods the driver held counted as idle (``idle_periods``), not missed; the
missed share of the active periods only; and no cycle WARN (its window is the last
10 s). The goal is set to 1 % here, above this shared machine's own losses (the floor
probe loses up to 0.1 % beside a graph), far below what the inactive time made of it
before: about 37 % missed and a WARN for the rest of the run. Every wait is bounded; the
graph is stopped by its session.
"""

import os
import signal
import sys
import time

import pytest

import procs
from test_ros2_cli import spawn

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']
GOAL = 0.01
OFF_S, ON_S, CYCLES, THEN_S = 1.0, 1.0, 5, 11.0
#: lifecycle_msgs Transition ids
ACTIVATE, DEACTIVATE = 3, 4


def _change(executor, client, transition):
    from lifecycle_msgs.srv import ChangeState
    req = ChangeState.Request()
    req.transition.id = transition
    fut = client.call_async(req)
    assert procs.spin_until(executor, fut.done, 10.0), 'no answer to change_state'
    assert fut.result().success, transition


def test_driver_cycles_are_not_missed_cycles_and_the_warning_clears(ctx, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    log = tmp_path / 'bringup.log'
    proc = spawn(dict(os.environ), BRINGUP + [
        '--scenario', 'sine', '--sync', 'realtime', '--duration', '45',
        '-p', 'simulated_actuator:cycle_goal_missed_share:=%g' % GOAL], log)
    try:
        assert procs.wait_log(log, 'bringup: graph up', 60.0, proc), log.read_text()[-3000:]
        node, executor, client = procs.change_state_client(ctx, '/actuator_driver')
        plant = {}

        def on_diag(msg):
            for st in msg.status:
                if st.name.rsplit('/', 1)[-1] == 'simulated_actuator':
                    plant.update(level=st.level, message=st.message, t=time.monotonic(),
                                 **{kv.key: kv.value for kv in st.values})
        node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 50)
        for _ in range(CYCLES):
            _change(executor, client, DEACTIVATE)
            procs.spin_until(executor, lambda: False, OFF_S)
            _change(executor, client, ACTIVATE)
            procs.spin_until(executor, lambda: False, ON_S)
        procs.spin_until(executor, lambda: False, THEN_S)
        t0 = time.monotonic()
        assert procs.spin_until(executor, lambda: plant.get('t', 0) > t0, 5.0), plant
        print('plant after the cycles: %s' % {k: plant[k] for k in (
            'level', 'message', 'periods', 'idle_periods', 'missed_cycles', 'missed_share',
            'recent_missed_share') if k in plant})
        idle = int(plant['idle_periods'])
        assert idle >= 0.8 * CYCLES * OFF_S * 1000, plant     # the held time: idle
        assert float(plant['missed_share']) <= GOAL, plant     # of the active periods
        assert 'of the cycles' not in plant['message'], plant  # no cycle WARN
        executor.remove_node(node)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        procs.stop(proc, 20.0)
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
