# SPDX-License-Identifier: Apache-2.0
"""
HELD: the one :class:`fiber_align.alignment.hold.Hold`, alone and in the three sequencers.

The class on its own (the return rule, the light check, the timeouts), then the three old
HELD cases driven through it by the real sequencers on their offline benches: the 1-D
sequencer whose driver drops the actuator to 0 m while down, the 2-D sequencer held by its
driver's ``drive_held`` (light at the held point: a re-peak; a DARK point, the target moved
while held: the search again, the case the old 2-D copy re-peaked into), the station held by
one axis. Every machine owns the same class and the same step, so the rule is one.
"""

import numpy as np
import pytest

from fiber_align.alignment import hillclimb2d as hc
from fiber_align.alignment import sequencer as sq
from fiber_align.alignment import sequencer2d as s2d
from fiber_align.alignment import station as st
from fiber_align.alignment import station_serial as ser
from fiber_align.alignment.hold import Hold
from fiber_align.alignment.machine import Machine
from fiber_align.alignment.states import FAULT, HELD, PEAKING, SEARCHING, TRACKING
from fiber_align.simulation import alignment2d_scenarios as sc2
from fiber_align.simulation import alignment_bench as ab
from fiber_align.simulation import alignment_scenarios as sc1
from fiber_align.simulation import station_scenarios as scs
from fiber_align.simulation.seeds2d import graph_period_s

TOL, N, TIMEOUT = 0.1e-6, 3, 0.5


def _hold(center=(1.0,)):
    log = []
    h = Hold(TOL, N, TIMEOUT, log.append)
    h.enter(0.0, TRACKING, [10e-6, 20e-6], center, down=('x',), why='x/driver tripped')
    return h, log


def test_the_hold_waits_for_the_re_arm_and_times_out_with_the_reason():
    h, _ = _hold()
    assert 'driver of x down during TRACKING at (10.00, 20.00) um (x/driver ' \
        'tripped)' in h.reason
    assert h.step(0.4, [0.0, 0.0], 1e-3, False, 1e-9) == (None, '')
    nxt, why = h.step(TIMEOUT + 1e-3, [0.0, 0.0], 1e-3, False, 1e-9)
    assert nxt == FAULT and why.startswith('driver inactive: a driver held its output for '
                                           'more than 0.5 s') and 'x/driver tripped' in why


def test_the_return_is_settle_samples_within_the_tolerance_with_a_reading():
    h, log = _hold()
    held = np.array([10e-6, 20e-6])
    near, off = held + 0.9 * TOL, held + np.array([0.0, 1.1 * TOL])
    t = 1.0
    assert h.step(t, off, 1e-3, True, 1e-9) == (None, '')           # the re-arm
    assert log[-1].startswith('drivers back after')
    for pos in (near, near, off, near, near):                        # a miss restarts it
        t += 1e-3
        assert h.step(t, pos, 1e-3, True, 1e-9) == (None, '')
    assert h.step(t + 1e-3, near, None, True, 1e-9) == (None, '')    # decide on a reading
    assert h.step(t + 2e-3, near, 1e-3, True, 1e-9) == (PEAKING, '')
    assert h.reason == ''


@pytest.mark.parametrize('center, pw, why', [
    (None, 1e-3, 'no light before the trip'),
    ((1.0,), 1e-9, 'no light at the held point (10.00, 20.00) um after the re-arm')])
def test_no_re_peak_point_or_no_light_there_searches_again(center, pw, why):
    h, _ = _hold(center)
    for k in range(N + 1):
        nxt = h.step(1.0 + k * 1e-3, [10e-6, 20e-6], pw, True, 1e-9)
    assert nxt == (SEARCHING, why)


def test_axes_that_do_not_return_fault_and_a_new_trip_restarts_the_wait():
    h, log = _hold()
    assert h.step(1.0, [0.0, 0.0], 1e-3, True, 1e-9) == (None, '')
    assert h.step(1.2, [0.0, 0.0], 1e-3, False, 1e-9) == (None, '')  # down again
    assert 'down again while returning' in log[-1]
    assert h.step(1.2 + 0.9 * TIMEOUT, [0.0, 0.0], 1e-3, False, 1e-9) == (None, '')
    assert h.step(2.0, [0.0, 0.0], 1e-3, True, 1e-9) == (None, '')
    nxt, why = h.step(2.0 + TIMEOUT + 1e-3, [0.0, 0.0], 1e-3, True, 1e-9)
    assert nxt == FAULT and why.startswith('actuator does not return to the held setpoint '
                                           '(10.00, 20.00) um')


@pytest.mark.parametrize('make', [
    lambda: sq.Sequencer(), lambda: s2d.Sequencer2D(period_s=1e-3),
    lambda: hc.HillClimb2D(period_s=1e-3), lambda: st.Station(period_s=1e-3),
    lambda: ser.SerialStation(period_s=1e-3)])
def test_every_machine_owns_the_one_hold_and_steps_it_the_same_way(make):
    seq = make()
    assert type(seq.hold) is Hold
    assert type(seq)._do_held is Machine._do_held and type(seq)._hold is Machine._hold
    assert seq.hold.tolerance_m == seq.p['settle_tolerance_m']
    assert seq.hold.samples == seq.p['settle_samples']
    assert seq.hold.timeout_s == seq.p['driver_down_timeout_s']


def _returned_at(states, y, held, tol, n, k_rearm):
    """Return the period index (after ``k_rearm``) of the first state other than HELD."""
    k = next(i for i in range(k_rearm, len(states)) if states[i] != HELD)
    # the decision (period k) took the n readings up to its own, all within the tolerance
    # of the held point, and came at once: the reading before them was not
    err = np.abs(y[k - n:k + 1] - held)
    assert np.all(err[1:] < tol) and err[0] >= tol, err
    return k


def test_1d_held_in_tracking_returns_by_the_rule_then_re_peaks():
    """1-D: a driver down drops the actuator to 0 m; back at the held point: a re-peak."""
    b = ab.build(seed=4, loop=ab.FirstOrderLoop(seed=4), slot_m=33e-6, record=True)
    assert sc1.align_bench(b)['state'] == TRACKING
    b.run_until(b.t + 0.1)
    b.driver_active = False
    b.run_until(b.t + 0.2)
    assert b.seq.state == HELD and b.loop.position_m < 1e-6
    held = b.seq.setpoint_m
    k_rearm = b.k
    b.driver_active = None
    b.run_until(b.t + 1.0, lambda x: x.seq.state in (TRACKING, FAULT))
    assert b.seq.state == TRACKING, b.seq.fault_reason
    arr = b.trace()
    k = _returned_at(arr['state'], arr['y'], held, b.seq.p['settle_tolerance_m'],
                     int(b.seq.p['settle_samples']), k_rearm)
    assert arr['state'][k] == PEAKING
    texts = [str(e[2]) for e in b.seq.events]
    assert any(x.startswith('driver back: local re-peak') for x in texts)
    assert not any('searching again' in x for x in texts)
    b.run_until(b.t + 0.02)
    assert b.true_loss() < 0.05


def _bench2d(target):
    b = sc2.build(seed=2, target=target)
    b.run_until(0.02)
    assert b.seq.align()[0]
    b.run_until(b.t + 3.0, lambda x: x.seq.state in (TRACKING, FAULT))
    assert b.seq.state == TRACKING, b.seq.fault_reason
    b.run_until(b.t + 0.05)
    return b


def test_2d_held_with_light_at_the_held_point_re_peaks_there():
    b = _bench2d((20e-6, 30e-6))
    b.seq.driver_held(True, s2d.DRIVERS[0])
    assert b.seq.state == HELD and 'driver of x down during TRACKING' in b.seq.hold_reason
    b.run_until(b.t + 0.05)
    b.seq.driver_held(False, s2d.DRIVERS[0])
    b.run_until(b.t + 2.0, lambda x: x.seq.state in (TRACKING, FAULT))
    assert b.seq.state == TRACKING, b.seq.fault_reason
    texts = [str(e[2]) for e in b.seq.events]
    assert any(x.startswith('drivers back: switching on to') for x in texts)
    assert not any('searching again' in x for x in texts)
    b.run_until(b.t + 0.05)
    assert b.true_loss() < 0.1


def test_2d_held_then_back_at_a_dark_point_searches_again_and_finds_the_light():
    """The target moved 25 um while the driver was down: no re-peak around a dark point."""
    b = _bench2d((20e-6, 30e-6))
    b.seq.driver_held(True, s2d.DRIVERS[1])
    assert b.seq.state == HELD
    tg = b.link.coupling.target
    tg.p0 = (45e-6, tg.p0[1])
    b.run_until(b.t + 0.05)
    b.seq.driver_held(False, s2d.DRIVERS[1])
    b.run_until(b.t + 0.1, lambda x: x.seq.state != HELD)
    assert b.seq.state == SEARCHING, (b.seq.state, b.seq.events[-3:])
    assert any('no light at the held point' in str(e[2]) and 'searching again' in str(e[2])
               for e in b.seq.events)
    b.run_until(b.t + 5.0, lambda x: x.seq.state in (TRACKING, FAULT))
    assert b.seq.state == TRACKING, b.seq.fault_reason
    b.run_until(b.t + 0.05)
    assert b.true_loss() < 0.1
    assert abs(b.seq.aligned[0] - 45e-6) < 0.5e-6


@pytest.fixture(scope='module')
def rig():
    return scs.StationRig('composite', graph_period_s(), 0)


def test_station_held_by_one_axis_then_a_dark_point_searches_again(rig):
    """The output facet moved 8 um while one driver was down: the station searches again."""
    b = scs.build(2, 'concurrent', rig=rig)
    assert scs.align_bench(b)['state'] == TRACKING
    b.driver_active = (True, True, True, False)
    b.step()
    assert b.seq.state == HELD and 'driver of y_out down' in b.seq.hold_reason
    tg = b.link.coupling.facets[1].target
    tg.p0 = (tg.p0[0] + 8e-6, tg.p0[1])
    b.run_until(b.t + 0.05)
    b.driver_active = None
    b.run_until(b.t + 0.1, lambda x: x.seq.state != HELD)
    assert b.seq.state == SEARCHING, b.seq.events[-3:]
    assert any('no light at the held point' in str(e[2]) for e in b.seq.events)
    b.run_until(b.t + 20.0, lambda x: x.seq.state in (TRACKING, FAULT))
    assert b.seq.state == TRACKING, b.seq.fault_reason
    b.run_until(b.t + 0.05)
    assert b.true_loss() < 0.1
