# SPDX-License-Identifier: Apache-2.0
"""
The sequencers' view of their drivers (``alignment.driver_state``), pure.

What a driver publishes (``drive_held``, its lifecycle transitions, ``/diagnostics``)
decides whether the sequencer may move the light: an active state leaves at once (the
1-D and the 2-D sequencer to HELD) with the driver's reason, a command that
moves the light is refused while a driver is down, and a re-activated driver whose
``drive_held`` false is still on its way does not refuse the first ``align``.
"""

import pytest

from fiber_align.alignment import sequencer as sq
from fiber_align.alignment import sequencer2d as s2d
from fiber_align.alignment.driver_state import DriverState
from fiber_align.simulation import alignment_bench as ab, alignment_scenarios as sc


def test_nothing_heard_is_unknown_and_nothing_refused():
    d = DriverState()
    assert d.active is None and d.reason == '' and d.refusal() is None


def test_drive_held_alone_decides_without_lifecycle_events():
    d = DriverState()
    assert d.held(False)
    assert d.active is True and d.refusal() is None
    assert d.held(True)
    assert d.active is False and 'drive_held true' in d.reason
    why = d.refusal()
    assert why.startswith('refused: the driver is not active: actuator_driver holding')
    assert '~/enable true' in why and why.endswith('then align')
    assert not d.held(True)                     # no change, no news


@pytest.mark.parametrize('state', ['unconfigured', 'inactive', 'errorprocessing',
                                   'deactivating', 'finalized', 'configuring'])
def test_a_lifecycle_state_other_than_active_is_down_whatever_drive_held_said(state):
    d = DriverState()
    d.held(False)
    d.lifecycle('active')
    assert d.active is True
    assert d.lifecycle(state)
    assert d.active is False and state[:5] in d.reason.replace(' ', '')
    why = d.refusal()
    assert 'not active' in why and 'configure and activate' in why
    assert 'lifecycle_manager startup' in why


def test_lost_device_then_replug_and_reactivation_in_either_order():
    """The unplug's messages, then the re-plug's, each in both orders of the two topics."""
    for held_first in (True, False):
        d = DriverState()
        d.held(False)
        d.lifecycle('active')
        steps = [lambda: d.held(True), lambda: d.lifecycle('errorprocessing')]
        for s in steps if held_first else steps[::-1]:
            s()
            assert d.active is False
        d.lifecycle('unconfigured')
        assert 'unconfigured' in d.reason and d.refusal()
        d.lifecycle('configuring')
        d.lifecycle('inactive')
        d.lifecycle('activating')
        assert d.active is False and d.refusal()
        if held_first:                          # composed: drive_held false comes first
            d.held(False)
            assert d.active is False            # still activating
            d.lifecycle('active')
        else:                                   # the event first, the false in flight
            d.lifecycle('active')
            assert d.active is False and d.pending
            assert d.refusal() is None          # the first align is not refused
            d.held(False)
        assert d.active is True and not d.pending and d.reason == ''


def test_a_held_heard_after_the_activation_is_not_pending():
    d = DriverState()
    d.lifecycle('active')
    d.held(False)
    d.held(True)                                # a trip, or ~/enable false
    assert d.active is False and not d.pending and d.refusal()


def test_diagnostics_count_only_until_drive_held_is_heard():
    d = DriverState()
    assert d.diagnostics(False)
    assert d.active is False and 'ERROR' in d.reason
    d.diagnostics(True)
    assert d.active is True
    d.diagnostics(False)
    d.held(False)                               # drive_held wins from now on
    assert d.active is True


def test_a_vanished_publisher_is_lost_until_the_driver_publishes_again():
    d = DriverState()
    d.held(False)
    assert d.gone()
    assert d.active is False and 'process is gone' in d.reason
    assert 'start the driver' in d.refusal()
    d.held(True)                                # a new driver process: held until active
    assert 'process is gone' not in d.reason


def test_two_drivers_one_down_is_down_both_named():
    d = DriverState(s2d.DRIVERS)
    for n in s2d.DRIVERS:
        d.held(False, n)
    assert d.active is True
    d.lifecycle('inactive', 'y/actuator_driver')
    assert d.active is False and d.reason.startswith('y/actuator_driver inactive')
    d.held(True, 'x/actuator_driver')
    assert 'x/actuator_driver' in d.reason and 'y/actuator_driver' in d.reason


def _tracking_bench():
    b = ab.build(seed=4, loop=ab.FirstOrderLoop(seed=4), slot_m=33e-6, record=False)
    b.seq.driver_held(False)
    b.seq.driver_lifecycle('active')
    m = sc.align_bench(b)
    assert m['state'] == sq.TRACKING
    return b


def test_sequencer_leaves_tracking_on_the_message_not_at_the_next_sample():
    b = _tracking_bench()
    n, t = len(b.seq.events), b.seq._t
    assert b.seq.driver_lifecycle('errorprocessing')
    assert b.seq.state == sq.HELD and b.seq._t == t        # no update in between
    r = b.seq.status()['hold_reason']
    assert r.startswith('driver down during TRACKING at ')
    assert 'actuator_driver in error processing' in r
    assert b.seq.events[n][1] == sq.HELD
    ok, why = b.seq.align()
    assert not ok and 'not active' in why and 'activate' in why
    assert b.seq.state == sq.HELD
    ok, why = b.seq.switch(True)
    assert not ok and 'not active' in why
    # the re-plug: activated, the drive_held false still on its way
    b.seq.driver_lifecycle('unconfigured')
    b.seq.driver_held(True)
    b.seq.driver_lifecycle('inactive')
    b.seq.driver_lifecycle('active')
    ok, msg = b.seq.align()
    assert ok and msg == 'alignment started'
    b.run_until(b.t + 0.005)
    assert b.seq.state == sq.HELD                           # held until the false comes
    b.seq.driver_held(False)
    b.run_until(b.t + 1.0, lambda bb: bb.seq.state in (sq.TRACKING, sq.FAULT))
    assert b.seq.state == sq.TRACKING, b.seq.fault_reason


def test_trip_while_tracking_holds_then_the_driver_rearms():
    b = _tracking_bench()
    assert b.seq.driver_held(True)                          # a watchdog trip
    assert b.seq.state == sq.HELD
    assert 'holding its output' in b.seq.status()['hold_reason']
    b.seq.driver_held(False)
    b.run_until(b.t + 1.0, lambda bb: bb.seq.state == sq.TRACKING)
    assert b.seq.state == sq.TRACKING


def test_align_replaces_the_automatic_repeak_but_not_a_users_alignment():
    b = _tracking_bench()
    b.seq.driver_held(True)
    b.seq.driver_held(False)
    b.run_until(b.t + 0.5, lambda bb: bb.seq.state == sq.PEAKING)
    assert b.seq.state == sq.PEAKING                # the re-peak after the re-arm
    ok, msg = b.seq.align()
    assert ok and b.seq.state == sq.SEARCHING, msg
    ok, msg = b.seq.align()                         # the user's own: busy
    assert not ok and 'busy' in msg
    b.run_until(b.t + 1.0, lambda bb: bb.seq.state in (sq.TRACKING, sq.FAULT))
    assert b.seq.state == sq.TRACKING, b.seq.fault_reason


def test_idle_and_release_are_not_refused_or_moved_by_a_down_driver():
    seq = sq.Sequencer()
    seq.update(0.0, 0.0, 1e-10)
    assert not seq.driver_held(True)
    assert seq.state == sq.IDLE
    assert seq.release()[0]
    ok, why = seq.align()
    assert not ok and seq.state == sq.RELEASING and 'drive_held true' in why


def test_sequencer2d_holds_on_the_message_and_refuses_align():
    seq = s2d.Sequencer2D(period_s=1e-3)
    for n in s2d.DRIVERS:
        seq.driver_held(False, n)
        seq.driver_lifecycle('active', n)
    seq.update(0.0, 0.0, 0.0, 1e-10)
    assert seq.align()[0] and seq.state == sq.SEARCHING
    assert seq.driver_lifecycle('inactive', 'x/actuator_driver')
    assert seq.state == sq.HELD
    assert '(x/actuator_driver inactive' in seq.status()['hold_reason']
    seq.driver_held(True, 'x/actuator_driver')
    ok, why = seq.align()
    assert not ok and 'x/actuator_driver' in why
    seq.driver_lifecycle('active', 'x/actuator_driver')     # drive_held false in flight
    assert seq.align()[0]
    seq.update(0.01, 0.0, 0.0, 1e-10)                       # pending: no fault
    assert seq.state == sq.SEARCHING
    seq.driver_held(False, 'x/actuator_driver')
    assert seq.drivers.active is True and seq.state == sq.SEARCHING
    seq.driver_held(True, 'x/actuator_driver')              # a trip after the activation
    assert seq.state == sq.HELD and 'drive_held true' in seq.status()['hold_reason']
