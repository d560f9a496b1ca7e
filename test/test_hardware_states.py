# SPDX-License-Identifier: Apache-2.0
"""
The sequencer's state agrees with its driver's on the hardware graph (the emulators).

The amplifier unplugged mid-TRACKING: the driver loses its device and ends unconfigured;
the sequencer leaves TRACKING for HELD, with the driver's reason, within one diagnostics
period of the driver's transition; ``align`` is refused while the driver is not active
(the response says so and what to do) and the sequencer stays HELD; after the re-plug
and the driver's re-activation (``lifecycle_manager/startup``) the first ``align`` is
accepted and ends in TRACKING.
"""

import threading
import time

import pytest

pytestmark = pytest.mark.ros


def test_unplugged_amplifier_holds_refuses_align_and_the_first_align_after_replug_works():
    from lifecycle_msgs.msg import TransitionEvent
    from std_srvs.srv import Trigger

    from fiber_align.graph.hardware import build_hardware
    from fiber_align.hardware.bench import emulated
    from fiber_align.bringup.hardware import HardwareRun
    with emulated(seed=2, slot_position_m=20e-6) as (bench, mdt, pm):
        g = build_hardware(port=mdt.port, visa_resource=pm.resource)
        period_s = float(g.node_params('alignment_sequencer')['diagnostics_period_s'])
        hw = HardwareRun(g)
        try:
            hw.start()
            events, lock = [], threading.Lock()

            def on_event(msg):
                with lock:
                    events.append((time.monotonic(), msg.goal_state.label))
            hw.obs.node.create_subscription(TransitionEvent, 'actuator_driver/transition_event',
                                            on_event, 10)
            assert hw.align()[0], hw.status
            time.sleep(0.2)
            assert hw.status['state'] == 'TRACKING', hw.status

            def when(label):
                with lock:
                    return next((t for t, lb in events if lb == label), None)

            t_unplug = time.monotonic()
            mdt.unplug()
            t_left = None
            end = t_unplug + 3.0
            while time.monotonic() < end and (t_left is None or when('unconfigured') is None):
                if t_left is None and hw.status.get('state') != 'TRACKING':
                    t_left = time.monotonic()
                time.sleep(0.002)
            t_unconf = when('unconfigured')
            assert t_unconf is not None, 'the driver did not end unconfigured: %s' % events
            assert t_left is not None, 'the sequencer stayed TRACKING: %s' % hw.status
            assert t_left - t_unconf <= period_s, (t_left - t_unconf, hw.status)
            st = hw.status
            assert st['state'] == 'HELD', st
            assert st['hold_reason'].startswith('driver down during TRACKING'), st
            assert 'actuator_driver' in st['hold_reason'], st
            # align while the driver is not active: refused with the reason, still HELD
            align = hw.obs.client(Trigger, 'align')
            res = hw.call(align, Trigger.Request())
            assert not res.success, res.message
            assert 'the driver is not active' in res.message, res.message
            assert 'unconfigured' in res.message and 'activate' in res.message, res.message
            time.sleep(0.1)
            assert hw.status['state'] == 'HELD', hw.status
            # the re-plug: the manager configures and activates; the first align works
            mdt.plug()
            startup = hw.obs.node.create_client(Trigger, 'lifecycle_manager/startup')
            assert hw.call(startup, Trigger.Request(), 10.0).success
            ok, wall = hw.align()
            assert ok, hw.status
            assert wall < 5.0
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes


def test_a_driver_process_that_exits_holds_the_sequencer_within_a_diagnostics_period():
    """The driver's process stopped (SIGINT: it ramps to safe, publishes nothing more)."""
    import signal

    from fiber_align.graph.hardware import build_hardware
    from fiber_align.hardware.bench import emulated
    from fiber_align.bringup.hardware import HardwareRun
    with emulated(seed=2, slot_position_m=20e-6) as (bench, mdt, pm):
        g = build_hardware(port=mdt.port, visa_resource=pm.resource, composed='false')
        period_s = float(g.node_params('alignment_sequencer')['diagnostics_period_s'])
        hw = HardwareRun(g)
        try:
            hw.start()
            assert hw.align()[0], hw.status
            drv = next(c for c in hw.children if c.name == 'actuator_driver')
            drv.proc.send_signal(signal.SIGINT)
            drv.proc.wait(timeout=10.0)
            t_exit = time.monotonic()
            end = t_exit + 3.0
            while time.monotonic() < end and hw.status.get('state') == 'TRACKING':
                time.sleep(0.002)
            t_left = time.monotonic()
            st = hw.status
            assert st['state'] == 'HELD', st
            assert t_left - t_exit <= period_s + 0.1, t_left - t_exit
            assert 'process is gone' in st['hold_reason'], st
            assert drv.proc.returncode == 0
        finally:
            codes = hw.stop()
    assert all(c == 0 for n, c in codes.items()), codes
