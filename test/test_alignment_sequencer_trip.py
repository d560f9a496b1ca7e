# SPDX-License-Identifier: Apache-2.0
"""
A driver that holds its output mid-align: the sequencer holds, waits and re-peaks.

The pure core against the first-order stand-in loop, whose tripped driver ramps the
actuator to the safe 0 m whatever the setpoint: a trip in the search, the peak sweep,
after the fit or while tracking, then the re-arm, ends TRACKING at the peak; a driver
that stays down past ``driver_down_timeout_s`` ends in FAULT with the reason. On the
realtime 1-D align graph (the graph description, started by bringup's harness), the
driver disabled mid-align and while tracking, then re-enabled (``actuator_driver/enable``):
the sequencer ends TRACKING within 0.1 dB of the optics' true peak.
"""

import time

import numpy as np
import pytest

from fiber_align.alignment import sequencer as sq
from fiber_align.simulation import alignment_bench as ab, alignment_scenarios as sc

SLOT = 33e-6


def _bench(seed=4, slot=SLOT, **seq):
    params = dict(sq.Sequencer().p, **seq)
    return ab.build(seed=seed, loop=ab.FirstOrderLoop(seed=seed), slot_m=slot,
                    record=False, seq_params=params)


def _step(b, up=True):
    """
    Run one control period of the bench (its production step); return the setpoint (m).

    ``up`` False: the bench's driver holds its output, the actuator goes to its safe 0 m.
    """
    b.driver_active = up
    b.step()
    return b.seq.setpoint_m


def _run(b, seconds, up=True, stop=None):
    b.driver_active = up
    b.run_until(b.t + seconds, stop)


def _loss_db(b, seconds=0.02):
    """Mean true loss (dB) over the next ``seconds`` (s) of steps."""
    losses = []
    for _ in range(int(round(seconds / b.period_s))):
        _step(b)
        losses.append(b.true_loss())
    return float(np.mean(losses))


def _trip_and_rearm(b, down_s=0.2):
    """Hold the driver down ``down_s`` (s); assert the setpoint holds; re-arm, run to TRACKING."""
    before = b.seq.state
    sp = _step(b, up=False)
    assert b.seq.state == sq.HELD, (before, b.seq.fault_reason)
    assert 'driver down during %s' % before in b.seq.status()['hold_reason']
    n = int(round(down_s / b.period_s))
    held = [_step(b, up=False) for _ in range(n)]
    assert b.seq.state == sq.HELD
    assert max(abs(r - sp) for r in held) == 0.0        # nothing moves while held
    assert b.loop.position_m < 1e-6                      # the actuator went to 0 m
    _run(b, 1.0, stop=lambda bb: bb.seq.state in (sq.TRACKING, sq.FAULT))
    assert b.seq.state == sq.TRACKING, b.seq.fault_reason
    return before


def _align_until(b, cond, max_s=1.0):
    _run(b, 0.02)
    b.seq.align()
    _run(b, max_s, stop=cond)
    assert cond(b), (b.seq.state, b.seq.status()['phase'], b.seq.fault_reason)


@pytest.mark.parametrize('where', ['tracking', 'first sweep', 'goto_peak', 'verify'])
def test_trip_then_rearm_ends_tracking_at_the_peak(where):
    b = _bench()
    if where == 'tracking':
        assert sc.align_bench(b)['state'] == sq.TRACKING
        _run(b, 0.1)
    elif where == 'first sweep':
        _align_until(b, lambda bb: bb.seq.state == sq.PEAKING and len(bb.seq._samples) > 4)
    else:
        _align_until(b, lambda bb: bb.seq.status()['phase'] == where)
    before = _trip_and_rearm(b)
    assert before in (sq.PEAKING, sq.TRACKING)
    texts = ' | '.join(str(e[2]) for e in b.seq.events)
    assert 'driver back' in texts and 'searching again' not in texts
    assert _loss_db(b) < 0.05


def test_rearm_before_any_light_searches_again():
    b = _bench(slot=50e-6)
    _align_until(b, lambda bb: bb.seq.state == sq.SEARCHING and bb.seq._phase == 'scan'
                 and bb.seq.setpoint_m > 10e-6)
    _trip_and_rearm(b)
    texts = [str(e[2]) for e in b.seq.events]
    assert any('no light before the trip: searching again' in x for x in texts)
    states = [e[1] for e in b.seq.events]
    i_held = states.index(sq.HELD)
    assert sq.SEARCHING in states[i_held:]
    assert _loss_db(b) < 0.05


def test_light_gone_at_the_held_point_searches_again():
    b = _bench()
    assert sc.align_bench(b)['state'] == sq.TRACKING
    _step(b, up=False)
    assert b.seq.state == sq.HELD
    b.link.coupling.fiber_broken = True
    _run(b, 0.1, up=False)
    _run(b, 0.2, stop=lambda bb: bb.seq.state == sq.SEARCHING)
    assert b.seq.state == sq.SEARCHING
    assert any('no light at the held point' in str(e[2]) for e in b.seq.events)


def test_driver_down_past_the_timeout_faults_with_the_reason():
    b = _bench(driver_down_timeout_s=0.3)
    assert sc.align_bench(b)['state'] == sq.TRACKING
    _step(b, up=False)
    t_trip = b.t
    _run(b, 0.5, up=False, stop=lambda bb: bb.seq.state != sq.HELD)
    assert b.seq.state == sq.FAULT
    assert b.t - t_trip == pytest.approx(0.3, abs=3e-3)
    reason = b.seq.fault_reason
    assert 'driver inactive' in reason and 'more than 0.3 s' in reason
    assert 'during TRACKING' in reason and 'without a re-arm' in reason
    # a re-arm after the FAULT does not restart it: release clears it
    _run(b, 0.05)
    assert b.seq.state == sq.FAULT
    b.seq.release()
    _run(b, 0.2, stop=lambda bb: bb.seq.state == sq.IDLE)
    assert b.seq.state == sq.IDLE


def test_down_again_while_returning_holds_and_recovers():
    b = _bench()
    assert sc.align_bench(b)['state'] == sq.TRACKING
    _run(b, 0.1, up=False)
    assert b.seq.state == sq.HELD
    _step(b)                                      # back for one period
    _run(b, 0.05, up=False)                       # and down again
    assert b.seq.state == sq.HELD
    assert any('down again' in str(e[2]) for e in b.seq.events)
    _run(b, 1.0, stop=lambda bb: bb.seq.state in (sq.TRACKING, sq.FAULT))
    assert b.seq.state == sq.TRACKING, b.seq.fault_reason
    assert _loss_db(b) < 0.05


def test_commands_while_held():
    b = _bench()
    assert sc.align_bench(b)['state'] == sq.TRACKING
    _run(b, 0.05, up=False)
    assert b.seq.state == sq.HELD
    ok, _ = b.seq.switch(False)                   # off parks, as from any state
    assert ok and b.seq.state == sq.RELEASING
    _run(b, 0.2, up=False, stop=lambda bb: bb.seq.state == sq.IDLE)
    assert b.seq.state == sq.IDLE


def _wait(h, cond, timeout_s, what):
    """Wait (bounded, s wall) until ``cond()``; the harness raises if a process died."""
    h.obs.wait(cond, timeout_s, h.alive, what)


def _enable(h, on):
    from std_srvs.srv import SetBool
    res = h.obs.call(h.obs.client(SetBool, 'actuator_driver/enable'),
                     SetBool.Request(data=on), 10.0, h.alive)
    assert res.success, res.message


def _states(h):
    with h.obs.lock:
        return [st for _, st in h.obs.states]


def _sample_t(h, st):
    """Return the sample time (s, the observer's clock) of a state's last step."""
    return float(st['sample_time_s']) - h.obs.t0_ns * 1e-9


def _trip(h, down_s=0.3, bound_s=30.0):
    """
    Disable the driver until the sequencer is HELD, ``down_s`` (s) more, re-enable; wait.

    Returns the HELD status and the TRACKING status the sequencer reaches after it. A
    watchdog trip of a loaded machine is one more HELD the sequencer rides out; a driver
    that latched after repeated trips gets ``enable`` true again, as an operator would.
    """
    n = len(_states(h))
    _enable(h, False)
    _wait(h, lambda: any(st['state'] == 'HELD' for st in _states(h)[n:]), 10.0, 'HELD')
    held = next(st for st in _states(h)[n:] if st['state'] == 'HELD')
    time.sleep(down_s)
    _enable(h, True)
    end = time.monotonic() + bound_s
    while True:
        _wait(h, lambda: h.obs.status.get('state') in ('TRACKING', 'FAULT', 'HELD'),
              bound_s, 'a state after the re-arm')
        st = h.obs.status
        if st['state'] == 'TRACKING':
            # TRACKING that lasts (the sample time 0.3 s on, still the same state)
            t_track = _sample_t(h, st)
            _wait(h, lambda: h.obs.t and h.obs.t[-1] > t_track + 0.3, 20.0, 'samples')
            if h.obs.status is not None and h.obs.status == st:
                return held, st
        assert st['state'] != 'FAULT', st
        assert time.monotonic() < end, _states(h)[n:]
        if st['state'] == 'HELD':
            time.sleep(1.0)
            if h.obs.status == st:
                _enable(h, True)                 # a latched watchdog: re-arm it


def _true_loss_db(h, g, tracking, after_s=0.15, window_s=0.1):
    """Mean true loss (dB) of the measured displacement ``after_s`` into TRACKING (s)."""
    from fiber_align.graph.params import PLANT
    from fiber_align.plant.optics import OpticalLink
    link = OpticalLink.from_params(g.node_params(PLANT))
    t0 = _sample_t(h, tracking) + after_s
    with h.obs.lock:
        t, y = np.asarray(h.obs.t), np.asarray(h.obs.data['y'])
    n = min(t.size, y.size)
    t, y = t[:n], y[:n]
    y = y[(t >= t0) & (t < t0 + window_s)]
    assert y.size >= 20, y.size           # a loaded machine may skip plant ticks
    loss = float(np.mean(link.loss_db(0.0, y)))
    print('true loss %.4f dB at %.3f um (slot %.3f um), states %s' % (
        loss, np.mean(y) * 1e6, link.coupling.slot_position(0.0) * 1e6,
        [(st['state'], st.get('hold_reason') or st.get('fault_reason')) for st in _states(h)]))
    return loss


@pytest.mark.ros
@pytest.mark.slow
def test_trip_mid_align_on_the_graph_ends_tracking_at_the_peak():
    from std_srvs.srv import Trigger

    from fiber_align.graph.description import build
    from fiber_align.bringup.harness import Harness
    g = build(scenario='align', sync_mode='realtime')
    h = Harness(g, dict(streams={'y': 'displacement'}, clock='y'))
    try:
        h.start()
        h.obs.start()
        h.run(True)
        _wait(h, lambda: h.obs.samples > 200 and h.obs.status.get('state') == 'IDLE',
              20.0, 'samples and IDLE')
        res = h.obs.call(h.obs.client(Trigger, 'align'), Trigger.Request(), 10.0, h.alive)
        assert res.success, res.message
        # the first trip lands in the search or the peak: mid-align
        held, tracking = _trip(h)
        assert held['hold_reason'].startswith('driver down during ')
        assert 'during TRACKING' not in held['hold_reason'], held
        assert _true_loss_db(h, g, tracking) < 0.1
        # and one while tracking: a local re-peak from the held point
        n = len(_states(h))
        held, tracking = _trip(h)
        assert 'during TRACKING' in held['hold_reason'], held
        # a local re-peak, no search (the observer's latched reader may skip a state)
        after = [st['state'] for st in _states(h)[n:]]
        assert after[0] == 'HELD' and after[-1] == 'TRACKING', after
        assert 'SEARCHING' not in after, after
        assert _true_loss_db(h, g, tracking) < 0.1
    finally:
        h.stop()
        h.close()
