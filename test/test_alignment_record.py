# SPDX-License-Identifier: Apache-2.0
"""The alignment's record from the sequencer's statuses (``fiber_align.alignment.record``)."""

import math

from fiber_align.alignment.record import AlignmentLog


def st(state, t, fault='', **kw):
    """Return a status as the sequencer publishes it."""
    return dict(state=state, sample_time_s=t, fault_reason=fault, **kw)


def test_five_cycles_a_part_each():
    """Five align/release cycles, the part set before each align: five rows, one part each."""
    log = AlignmentLog('run', reference_power_w=1e-3)
    got = []
    for k in range(5):
        t0 = 10.0 * k
        log.set_part('P%d' % k)
        got += log.on_status(st('SEARCHING', t0, align_sample=1000 * k))
        log.set_part('next')        # set during the alignment: the next one's
        log.on_power(1e-5)
        got += log.on_status(st('PEAKING', t0 + 0.04))
        log.on_power(9.9e-4)
        log.on_power(1.0e-3 * (1 - 0.01 * k))
        got += log.on_status(st('TRACKING', t0 + 0.08))
        log.on_power(1.0e-3 * (1 - 0.01 * k))
        got += log.on_status(st('RELEASING', t0 + 5.0, sample=1000 * k + 5000))
        got += log.on_status(st('IDLE', t0 + 5.1))
    assert [r['seq'] for r in got] == [1, 2, 3, 4, 5]
    assert [r['part_id'] for r in got] == ['P0', 'P1', 'P2', 'P3', 'P4']
    assert {r['final_state'] for r in got} == {'TRACKING'}
    for k, r in enumerate(got):
        assert math.isclose(r['time_to_first_light_s'], 0.04)
        assert math.isclose(r['time_to_peak_s'], 0.08)
        assert math.isclose(r['final_loss_db'], -10 * math.log10(1 - 0.01 * k))
        assert math.isclose(r['peak_power_w'], max(9.9e-4, 1e-3 * (1 - 0.01 * k)))
        assert r['samples'] == 5000


def test_a_fault_ends_the_alignment_with_its_reason():
    """FAULT ends it: state FAULT, the reason; no peak, no loss without power."""
    log = AlignmentLog('run')
    log.set_part('A')
    assert log.on_status(st('SEARCHING', 0.0)) == []
    assert log.on_status(st('SEARCHING', 0.5)) == []        # re-search: same alignment
    rows = log.on_status(st('FAULT', 2.0, fault='no light in the search range'))
    assert len(rows) == 1 and rows[0]['final_state'] == 'FAULT'
    assert rows[0]['fault_reason'] == 'no light in the search range'
    assert rows[0]['time_to_peak_s'] is None and rows[0]['final_loss_db'] is None
    assert log.on_status(st('IDLE', 3.0)) == [] and log.close() == []


def test_an_open_alignment_is_closed_with_the_run():
    """The run ends while TRACKING (or HELD): the row keeps that state."""
    log = AlignmentLog('run')
    log.on_status(st('SEARCHING', 0.0))
    log.on_status(st('PEAKING', 1.0))
    log.on_status(st('TRACKING', 2.0))
    log.on_status(st('HELD', 3.0))
    rows = log.close()
    assert [(r['seq'], r['final_state'], r['part_id']) for r in rows] == [(1, 'HELD', None)]
