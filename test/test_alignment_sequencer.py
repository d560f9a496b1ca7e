# SPDX-License-Identifier: Apache-2.0
"""Tests of the alignment sequencer state machine against a first-order stand-in loop."""

import math

import numpy as np
import pytest

from fiber_align.alignment import sequencer as sq
from fiber_align.alignment.search2d import fit_log_paraboloid_groups
from fiber_align.simulation import alignment_bench as ab, alignment_scenarios as sc


def test_log_parabola_fit_is_exact_for_the_gaussian_model():
    """The sweep's fit: the paraboloid fit with one group of one axis."""
    x = np.linspace(30e-6, 38e-6, 9)[:, None]
    p = 1e-3 * np.exp(-((x[:, 0] - 35.3e-6) / 5.2e-6) ** 2)
    (x0,), (c,), lp0 = fit_log_paraboloid_groups(x, p, ((0,),))
    assert x0 == pytest.approx(35.3e-6, abs=1e-12)
    assert c == pytest.approx(1 / 5.2e-6 ** 2, rel=1e-6)
    assert math.exp(lp0) == pytest.approx(1e-3, rel=1e-6)
    # one side only and with a known curvature
    (x0b,), _, _ = fit_log_paraboloid_groups(x[:4], p[:4], ((0,),), curvature=c)
    assert x0b == pytest.approx(35.3e-6, abs=1e-12)
    # a valley is not a peak
    assert fit_log_paraboloid_groups(x, 1e-3 / p, ((0,),)) is None


def test_commands_and_states_from_idle():
    seq = sq.Sequencer()
    assert seq.state == sq.IDLE
    ok, msg = seq.switch(True)
    assert not ok and 'align' in msg
    assert seq.update(0.0, 0.0, 1e-10) == pytest.approx(seq.p['park_position_m'])
    ok, _ = seq.align()
    assert ok and seq.state == sq.SEARCHING
    ok, msg = seq.align()
    assert not ok and 'busy' in msg
    ok, _ = seq.release()
    assert ok and seq.state == sq.RELEASING


def test_unknown_parameter_is_rejected():
    with pytest.raises(ValueError, match=r'sequencer parameters: .*unknown .*dither_amplitude'):
        sq.Sequencer(dither_amplitude=1.0)


@pytest.mark.parametrize('slot_um', [0.0, 12.0, 33.0, 64.0])
def test_align_reaches_the_peak_on_the_stand_in_loop(slot_um):
    r = sc.run('align', seed=2, loop='ideal', slot_m=slot_um * 1e-6)
    assert r['state'] == sq.TRACKING, r['fault_reason']
    assert r['final_loss_db'] <= 0.05
    assert r['time_to_peak_s'] <= 0.5
    assert r['peak_samples'] <= 60


def test_twenty_random_slots_stand_in_loop():
    trials, s = sc.align_trials(20, seed=11, loop='ideal')
    assert s['aligned'] >= 19
    assert s['silent_failures'] == 0
    slots = [t['slot_m'] for t in trials]
    assert min(slots) < 5e-6 and max(slots) > 60e-6      # the whole range is covered


def test_broken_fiber_faults_within_the_search_timeout():
    r = sc.run('align', seed=0, loop='ideal', slot_m=30e-6, fiber_broken=True)
    assert r['state'] == sq.FAULT
    assert 'no light found' in r['fault_reason']
    assert r['simulated_s'] - 0.02 <= sq.Sequencer().p['search_timeout_s'] + 0.002


@pytest.mark.parametrize('slot_um,word', [(70.0, 'rising at the end'),
                                          (90.0, 'no light found'),
                                          (-4.0, 'falls from the start')])
def test_slot_outside_the_reachable_range_says_so(slot_um, word):
    r = sc.run('align', seed=0, loop='ideal', slot_m=slot_um * 1e-6)
    assert r['state'] == sq.FAULT
    assert word in r['fault_reason']
    assert 'reachable' in r['fault_reason']


def _bench(slot=30e-6, loop=None, **kw):
    return ab.build(seed=4, loop=loop or ab.FirstOrderLoop(seed=4), slot_m=slot, **kw)


def test_silent_power_sensor_faults():
    b = _bench()
    b.run_until(0.02)
    b.seq.align()
    t0 = b.t
    y = b.loop.y_meas
    for k in range(30):
        b.seq.update(t0 + k * 1e-3, y, None)
    assert b.seq.state == sq.FAULT
    assert 'sensor silent' in b.seq.fault_reason


def test_a_constant_dark_reading_is_the_floor_a_frozen_lit_one_faults():
    """A meter clamped in the dark reads one value: the floor; lit and moving: frozen."""
    seq = sq.Sequencer()
    for k in range(15):
        seq.update(k * 1e-3, 0.0, 3e-10)
    seq.align()
    y = 0.0
    for k in range(15, 30):
        y = seq.update(k * 1e-3, y, 3e-10)
    assert seq.state == sq.SEARCHING and seq.floor == pytest.approx((3e-10, seq.p['dark_floor_w']))
    assert seq.threshold_w == pytest.approx(3e-10 + 6.0 * 1e-9)
    t_lit = 30e-3
    k = 30
    while seq.state != sq.FAULT and k < 1030:           # lit, one value, the axis moving
        y = seq.update(k * 1e-3, y, 1e-4)
        k += 1
    assert seq.state == sq.FAULT and 'power meter frozen' in seq.fault_reason
    assert k * 1e-3 - t_lit <= 1.0


def test_driver_inactive_flag_and_actuator_that_does_not_move():
    seq = sq.Sequencer()
    seq.update(0.0, 0.0, 1e-10)
    seq.align()
    seq.update(1e-3, 0.0, 1.2e-10, driver_active=False)
    assert seq.state == sq.HELD and 'driver down' in seq.status()['hold_reason']
    t_down = seq.p['driver_down_timeout_s']
    k = 2
    while seq.state == sq.HELD and k * 1e-3 < t_down + 0.01:
        seq.update(k * 1e-3, 0.0, 1.2e-10, driver_active=False)
        k += 1
    assert seq.state == sq.FAULT and 'driver inactive' in seq.fault_reason
    assert k * 1e-3 == pytest.approx(1e-3 + t_down, abs=3e-3)

    class Dead(ab.FirstOrderLoop):
        def step(self, r_m):
            return self.measure()

    b = _bench(loop=Dead(seed=1))
    b.run_until(0.02)
    b.seq.align()
    b.run_until(0.5, lambda bb: bb.seq.state == sq.FAULT)
    assert b.seq.state == sq.FAULT
    assert 'does not follow' in b.seq.fault_reason


def test_power_lost_while_tracking_faults_and_release_recovers():
    b = _bench()
    m = sc.align_bench(b)
    assert m['state'] == sq.TRACKING
    b.link.coupling.fiber_broken = True
    b.run_until(b.t + 0.1, lambda bb: bb.seq.state == sq.FAULT)
    assert b.seq.state == sq.FAULT
    assert 'power lost while tracking' in b.seq.fault_reason
    ok, msg = b.seq.switch(True)
    assert not ok and 'FAULT' in msg
    b.seq.release()
    b.run_until(b.t + 0.2, lambda bb: bb.seq.state == sq.IDLE)
    assert b.seq.state == sq.IDLE and b.seq.fault_reason == ''


def test_tracking_follows_1um_per_s_drift_stand_in():
    r = sc.run('track', seed=5, loop='ideal', duration_s=8.0, drift_m_per_s=1e-6)
    assert r['tracking_state'] == sq.TRACKING
    assert r['tracking_time_s'] == pytest.approx(8.0, abs=0.01)
    assert r['tracking_max_loss_db'] <= 0.1


def test_dither_costs_at_most_005_db():
    p = sq.Sequencer().p
    w = 5.2e-6
    peak_loss = 10 / math.log(10) * (p['dither_amplitude_m'] / w) ** 2
    assert peak_loss <= 0.05
    # measured: the mean true loss while tracking a fixed slot
    r = sc.run('track', seed=6, loop='ideal', duration_s=2.0, drift_m_per_s=0.0)
    assert r['tracking_mean_loss_db'] <= 0.05


def test_switch_cycles_do_not_drift_stand_in():
    r = sc.run('switch', seed=7, loop='ideal', slot_m=40e-6, cycles=60)
    assert r['cycles'] == 60 and not r['switch_faults']
    assert abs(r['cycle_loss_drift_db']) <= 0.02
    assert r['cycle_loss_max_db'] <= 0.05
    assert r['switch_rise_time_s'] <= 5e-3
