# SPDX-License-Identifier: Apache-2.0
"""
Align from anywhere on the 1-D hardware bench (the sensorless graph on the emulators).

``align`` while TRACKING five times in a row, each ending TRACKING within 0.1 dB of the
slot; then the amplifier unplugged (HELD), re-plugged and ``startup`` called: the
sequencer's own re-peak ends TRACKING with no ``align``, within 0.1 dB 3 s later. The
re-powered bimorph starts from rest, so the held point no longer matches the fiber:
before, the +-1.5 um re-peak FAULTed ("the 6 samples over 38.5..41.0 um do not show a
peak"); now a local sweep with no peak widens, then searches again (docs/alignment.md).
"""

import time

import pytest


@pytest.mark.ros  # starts processes
def test_align_five_times_while_tracking_then_replug_tracks_again():
    from std_srvs.srv import Trigger

    from fiber_align.bringup.hardware import HardwareRun
    from fiber_align.graph.hardware import build_hardware
    from fiber_align.hardware.bench import emulated
    with emulated(seed=3, slot_position_m=40e-6) as (bench, mdt, pm):
        hw = HardwareRun(build_hardware(port=mdt.port, visa_resource=pm.resource), quiet=False)
        try:
            hw.start()
            ok, _ = hw.align()
            assert ok, hw.status
            results = []
            for _ in range(5):
                time.sleep(0.3)
                assert hw.status.get('state') == 'TRACKING', hw.status
                ok, wall = hw.align()
                results.append((ok, round(wall, 2), hw.status.get('fault_reason')))
                time.sleep(0.2)
                results[-1] += (bench.true_loss_db(),)
            print('align while TRACKING (ok, wall s, fault, loss dB):', results)
            assert all(r[0] for r in results), results
            assert all(r[3] < 0.1 for r in results), results
            # the amplifier unplugged and re-plugged, startup: TRACKING with no align
            mdt.unplug()
            hw.wait(lambda: hw.status.get('state') == 'HELD', 2.0, 'sequencer HELD')
            time.sleep(0.5)
            mdt.plug()
            startup = hw.obs.node.create_client(Trigger, 'lifecycle_manager/startup')
            assert hw.call(startup, Trigger.Request(), 10.0).success
            t_startup = time.monotonic()
            hw.wait(lambda: hw.status.get('state') in ('TRACKING', 'FAULT'), 8.0,
                    'TRACKING again')
            assert hw.status['state'] == 'TRACKING', hw.status
            t_tracking = time.monotonic()
            # the held point is off by the bimorph's new hysteresis branch; where the
            # re-peak's verify missed, TRACKING climbs the rest (2 rad/s: about 1 s)
            hw.wait(lambda: hw.status.get('state') != 'TRACKING' or bench.true_loss_db() < 0.1,
                    3.0, 'within 0.1 dB while TRACKING')
            assert hw.status['state'] == 'TRACKING', hw.status
            print('startup to TRACKING: %.2f s, then to within 0.1 dB: %.2f s'
                  % (t_tracking - t_startup, time.monotonic() - t_tracking))
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes
