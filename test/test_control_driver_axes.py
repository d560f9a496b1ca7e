# SPDX-License-Identifier: Apache-2.0
"""
``DriverAxes``: the driver's per-axis rules for N axes, held together (pure, no ROS).

One axis is the 1-D driver: its drives are those of its ``DriverCore`` alone. Two axes:
a watchdog trip of one holds the other (it ramps to its own safe voltage on its fresh
input), both follow again once every input is fresh; lockstep pairs per axis, in order.
"""

import pytest

from fiber_align.control.driver import DriverCore
from fiber_align.control.driver_axes import (check_axis, DriverAxes, limit_updates,
                                             parameter_table, SHARED_KEYS)
from fiber_align.control.realtime import RECOVERY_S

PERIOD_S = 1e-3
LIMITS = dict(v_min=0.0, v_max=100.0, slew_rate_v_per_s=0.0, watchdog_timeout_s=0.05,
              safe_voltage_v=0.0, latch_trips=3, latch_window_s=10.0,
              safe_ramp_rate_v_per_s=2000.0)


def axes(*names, **per_axis):
    """Return ``{axis: params}``: LIMITS, each axis's own values from ``per_axis``."""
    return {a: dict(LIMITS, **per_axis.get(a or 'one', {})) for a in names}


def feed(drv, t0, t1, values, axes_fed=None):
    """Feed sensorless feedforwards ``{axis: V}`` every period over [t0, t1) with ticks."""
    out = []
    t = t0
    while t < t1:
        for a, v in values.items():
            if axes_fed is None or a in axes_fed:
                out += drv.feedforward(a, v, t, sensorless=True)
        out += drv.tick(t)
        t += PERIOD_S
    return out


def test_one_axis_drives_as_its_core_alone():
    """Unnamed axis, realtime with feedback: the drives equal DriverCore's own commands."""
    drv = DriverAxes(axes(''), PERIOD_S)
    core = DriverCore(**dict(LIMITS, ramp_period_s=PERIOD_S))
    drv.activate()
    seq = [(10.0, 1.0), (150.0, 0.0), (-20.0, 5.0), (40.0, -2.5)]
    got = []
    for i, (ff, fb) in enumerate(seq):
        t = i * PERIOD_S
        assert drv.feedforward('', ff, t) == []         # the feedback is not late
        got += drv.feedback('', fb, t)
    assert got == [('', core.command(ff, fb, i * PERIOD_S)) for i, (ff, fb) in enumerate(seq)]
    assert [v for _, v in got] == [11.0, 100.0, 0.0, 37.5]
    assert not drv.held


def test_inactive_or_disabled_drives_nothing_but_the_ramp_to_safe():
    drv = DriverAxes(axes('', one=dict(safe_voltage_v=5.0)), PERIOD_S)
    assert drv.held and drv.feedback('', 10.0, 0.0) == []
    drv.activate()
    drv.feedforward('', 50.0, 0.0)
    assert drv.feedback('', 0.0, 0.0) == [('', 50.0)]
    drv.enable(False, 0.0)
    assert drv.held
    # disabled: each input and tick moves toward 5 V at 2000 V/s, 2 V a period
    out = drv.feedback('', 0.0, PERIOD_S) + drv.tick(2 * PERIOD_S)
    assert [v for _, v in out] == pytest.approx([48.0, 46.0])
    out = feed(drv, 3 * PERIOD_S, 0.05, {})
    assert out[-1] == ('', 5.0) and drv.tick(0.06) == []    # at safe: nothing more
    drv.enable(True, 0.06)
    assert not drv.held


def test_one_axis_silent_holds_both_and_both_follow_again():
    drv = DriverAxes(axes('x', 'y'), PERIOD_S)
    drv.activate()
    feed(drv, 0.0, 0.1, {'x': 30.0, 'y': 40.0})
    assert (drv.cores['x'].v, drv.cores['y'].v) == (30.0, 40.0)
    # y silent: its watchdog trips after 50 ms; x, still fed, ramps to its safe voltage too
    out = feed(drv, 0.1, 0.3, {'x': 30.0, 'y': 40.0}, axes_fed='x')
    ev = drv.take_events()
    assert [(k, a) for k, a, _ in ev] == [('trip', 'y')]
    assert ev[0][2].startswith('watchdog: axis y: no fresh feedforward_voltage for 0.05 s')
    assert drv.held and drv.cores['x'].v == 0.0 and drv.cores['y'].v == 0.0
    assert [v for a, v in out if a == 'x'][-1] == 0.0
    # y back: after RECOVERY_S of fresh input both follow (and held ends)
    feed(drv, 0.3, 0.3 + RECOVERY_S + 0.05, {'x': 30.0, 'y': 40.0})
    assert not drv.held
    assert (drv.cores['x'].v, drv.cores['y'].v) == (30.0, 40.0)
    assert [k for k, _, _ in drv.take_events()] == ['back']


def test_both_axes_silent_then_back_do_not_wait_for_each_other():
    drv = DriverAxes(axes('x', 'y'), PERIOD_S)
    drv.activate()
    feed(drv, 0.0, 0.1, {'x': 30.0, 'y': 40.0})
    feed(drv, 0.1, 0.3, {})                     # both silent: both trip in one tick
    assert sorted(a for k, a, _ in drv.take_events() if k == 'trip') == ['x', 'y']
    feed(drv, 0.3, 0.3 + RECOVERY_S + 0.05, {'x': 30.0, 'y': 40.0})
    assert not drv.held and (drv.cores['x'].v, drv.cores['y'].v) == (30.0, 40.0)


def test_latch_after_the_trips_until_enable_or_activate():
    drv = DriverAxes(axes('x', 'y'), PERIOD_S)
    drv.activate()
    t = 0.0
    for _ in range(3):
        feed(drv, t, t + 0.05, {'x': 30.0, 'y': 40.0})
        feed(drv, t + 0.05, t + 0.15, {'x': 30.0}, axes_fed='x')
        t += 0.15
    assert drv.cores['y'].latched
    assert 'latch' in [k for k, _, _ in drv.take_events()]
    feed(drv, t, t + 0.1, {'x': 30.0, 'y': 40.0})
    assert drv.held and drv.cores['y'].v == 0.0 and drv.cores['x'].v == 0.0
    assert drv.enable(True, t + 0.1) == ['y']       # the operator's enable re-arms
    feed(drv, t + 0.1, t + 0.2, {'x': 30.0, 'y': 40.0})
    assert not drv.held and drv.cores['y'].v == 40.0


def test_lockstep_pairs_each_axis_in_order_and_keeps_pairs_while_inactive():
    drv = DriverAxes(axes('x', 'y'), PERIOD_S)
    assert drv.pair_ff('x', 10.0) == [] and drv.pair_fb('x', 1.0) == []   # kept
    drv.activate()
    assert drv.pair('x') == [('x', 11.0)]
    assert drv.pair_ff('y', 20.0) == [] and drv.pair_fb('y', -1.0) == [('y', 19.0)]
    assert drv.deactivate(0.0, lockstep=True) == [('x', 0.0), ('y', 0.0)]


def test_parameters_and_updates_name_each_axis():
    d = dict(LIMITS, channel='x', **{'y.v_max': 80.0})
    names = [row[0] for row in parameter_table(['x', 'y'], d)]
    assert names[:6] == ['x.v_min', 'x.v_max', 'x.safe_voltage_v', 'y.v_min', 'y.v_max',
                         'y.safe_voltage_v']
    assert dict((r[0], r[1]) for r in parameter_table(['x', 'y'], d))['y.v_max'] == 80.0
    assert [r[0] for r in parameter_table([''], d)][:3] == ['v_min', 'v_max',
                                                            'safe_voltage_v']
    assert names[6:] == list(SHARED_KEYS)
    assert limit_updates(['x', 'y'], {'y.v_max': 90, 'latch_trips': 2.0, 'x.channel': 'z',
                                      'rate_hz': 5.0}) == ({
                                          'y': {'v_max': 90.0, 'latch_trips': 2},
                                          'x': {'latch_trips': 2}}, None)
    limits = dict(LIMITS, field_limit_v=150.0, coercive_field_v=120.0, depoling_fraction=0.33)
    assert limit_updates([''], {'v_max': 90.0}, lambda a, n: dict(limits, **n)) == (
        {'': {'v_max': 90.0}}, None)
    new, why = limit_updates(['x', 'y'], {'y.v_max': 160.0}, lambda a, n: dict(limits, **n))
    assert new == {'y': {'v_max': 160.0}} and 'field limit' in why
    assert check_axis(limits) is None
    assert 'field limit' in check_axis(dict(limits, v_max=160.0))
    assert 'must exceed' in check_axis(dict(limits, v_min=50.0, v_max=40.0))


def test_a_foreign_publisher_holds_every_axis_where_it_is_until_gone_and_rearmed():
    """Issue 39.1: a second graph's 100 V never reaches the output; re-arming needs both."""
    drv = DriverAxes(axes('x', 'y'), PERIOD_S)
    drv.activate()
    out = feed(drv, 0.0, 0.01, {'x': 30.0, 'y': 40.0})
    assert out[-2:] == [('x', 30.0), ('y', 40.0)] and not drv.held
    drv.intrusion('/x/feedforward_voltage: 2 publishers, 1 expected: foreign /intruder')
    (kind, _, text), = drv.take_events()
    assert kind == 'foreign' and '/intruder' in text and '30 V, 40 V' in text and drv.held
    # the inputs (the foreign 100 V among them) are not followed; no watchdog trip
    out = feed(drv, 0.01, 0.2, {'x': 100.0, 'y': 100.0}) + feed(drv, 0.2, 0.4, {})
    assert {v for _, v in out} == {30.0, 40.0}
    assert drv.cores['x'].watchdog_count == 0 and not drv.take_events()
    # re-armed while it is there: refused, still held
    drv.enable(True, 0.4)
    assert drv.take_events()[0][0] == 'foreign' and drv.held
    drv.intrusion(None)                         # gone: still held until re-armed
    assert drv.take_events()[0][0] == 'gone' and drv.held
    assert {v for _, v in feed(drv, 0.4, 0.5, {'x': 100.0, 'y': 100.0})} == {30.0, 40.0}
    drv.enable(True, 0.5)
    assert drv.take_events()[0][0] == 'resume' and not drv.held
    assert feed(drv, 0.5, 0.502, {'x': 50.0, 'y': 60.0})[-2:] == [('x', 50.0), ('y', 60.0)]


def test_a_lifecycle_cycle_rearms_after_a_foreign_publisher_is_gone():
    drv = DriverAxes(axes(''), PERIOD_S)
    drv.activate()
    feed(drv, 0.0, 0.01, {'': 20.0})
    drv.intrusion('/drive_voltage: 2 publishers, 1 expected: foreign /actuator_driver')
    drv.intrusion(None)
    drv.deactivate(0.01, False)
    drv.activate()
    assert [k for k, _, _ in drv.take_events()] == ['foreign', 'gone', 'resume']
    assert not drv.held


def test_a_second_publisher_not_yet_named_holds_and_is_let_go_when_none_is_foreign():
    """A restarted node's expired writer: matched twice, then named as the owner alone."""
    drv = DriverAxes(axes(''), PERIOD_S)
    drv.activate()
    feed(drv, 0.0, 0.01, {'': 20.0})
    drv.intrusion('/feedback_voltage: 2 publishers matched, 1 expected', pending=True)
    assert drv.held is True and feed(drv, 0.01, 0.02, {'': 90.0})[-1] == ('', 20.0)
    drv.intrusion(None)                         # named: none foreign; no re-arm needed
    assert not drv.held and not drv.take_events()
    assert feed(drv, 0.02, 0.03, {'': 30.0})[-1] == ('', 30.0)
