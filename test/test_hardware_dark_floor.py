# SPDX-License-Identifier: Apache-2.0
"""
Dark is not dead on the hardware bench and the two-axis rig (emulated MDT693B + PM100).

The PM100 emulator clamps its readings at a floor (``--meter-floor``; the optics'
``floor_w``): in the dark it returns one value again and again, as meters that clamp below
their noise floor do. The rig's graph aligns on it (``bringup --rig --hardware --emulate
--meter-floor``, as a user starts it); with in-process emulators the 1-D bench's graph
and the rig's track within 0.1 dB of the best point, and a meter frozen mid-TRACKING is
named within 1 s.
"""

import json
import sys
import time

import pytest

from procs import run_bounded

#: the meter's clamp (W): -60 dBm, ten times the emulated detector's RMS dark noise
FLOOR_W = 1e-9


@pytest.mark.ros  # starts processes
def test_bringup_rig_hardware_emulate_with_a_constant_dark_floor(tmp_path):
    summary = tmp_path / 's.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--rig',
                             '--hardware', '--emulate', '--meter-floor', repr(FLOOR_W),
                             '--seed', '2', '--hold', '0.5', '--quiet', '--summary',
                             str(summary)], timeout=60)
    s = json.loads(summary.read_text())
    assert code == 0, (s, out[-2000:])
    assert s['aligned'] and s['final_state'] == 'TRACKING', s
    assert 'stuck' not in json.dumps(s)
    assert all(c == 0 for c in s['exit_codes'].values()), s['exit_codes']


def _bench(machine):
    """Return ``(emulated bench kwargs, graph builder)`` of the 1-D bench or the rig."""
    from fiber_align.graph.hardware import build_hardware
    from fiber_align.graph.hardware_rig import build_hardware_rig
    if machine == '1-D':                # the slot well inside the travel
        return dict(seed=0, slot_position_m=30e-6), build_hardware
    # well inside the reachable square
    return dict(seed=2, rig=True, position_x_m=30e-6, position_y_m=25e-6), build_hardware_rig


@pytest.mark.ros  # starts processes
@pytest.mark.parametrize('machine', ['1-D', 'rig'])
def test_graph_on_a_floored_meter_tracks_within_0p1_db_and_names_a_frozen_meter(machine):
    from fiber_align.bringup.hardware import HardwareRun
    from fiber_align.hardware.bench import emulated
    options, build = _bench(machine)
    with emulated(floor_w=FLOOR_W, **options) as (bench, mdt, pm):
        dark = {pm.measure_w() for _ in range(10)}
        assert dark == {FLOOR_W}, dark              # the meter's dark reading: one value
        hw = HardwareRun(build(port=mdt.port, visa_resource=pm.resource))
        try:
            hw.start()
            ok, wall = hw.align()
            assert ok, hw.status
            time.sleep(0.3)
            losses = []
            for _ in range(20):
                losses.append(bench.true_loss_db())
                time.sleep(0.01)
            assert hw.status['state'] == 'TRACKING', hw.status
            assert sum(losses) / len(losses) < 0.1, losses
            frozen = bench.detector_sample(pm.sample_time_s)
            bench.detector_sample = lambda dt_s: frozen     # the meter freezes
            t0 = time.monotonic()
            hw.wait(lambda: hw.status.get('state') in ('FAULT', 'HELD'), 3.0,
                    'FAULT or HELD after the meter froze')
            dt = time.monotonic() - t0
            why = hw.status.get('fault_reason') or hw.status.get('hold_reason')
            print('%s on a %g W floor: align %.2f s, loss %.4f dB; frozen meter named in '
                  '%.2f s: %s' % (machine, FLOOR_W, wall, sum(losses) / len(losses), dt, why))
            assert 'power meter frozen' in why, hw.status
            assert dt < 1.0, (dt, why)
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes


def test_1d_sensorless_bench_on_a_floored_meter_tracks_within_0p1_db():
    """The 1-D bench on the device protocols (in-process emulators, no ROS)."""
    from fiber_align.alignment import sequencer as sq
    from fiber_align.hardware.bench import emulated, SensorlessBench
    with emulated(seed=0, slot_position_m=30e-6, floor_w=FLOOR_W) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource, truth=bench.true_loss_db)
        try:
            sb.connect()
            sb.run(lambda b: False, 0.15)                   # IDLE readings: the floor
            assert {row[1] for row in sb.trace} == {FLOOR_W}
            ok, wall = sb.align(3.0)
            assert ok, sb.seq.fault_reason
            losses = sb.hold(0.3)
            assert sb.seq.state == sq.TRACKING and sum(losses) / len(losses) < 0.1, losses
        finally:
            sb.close()
