# SPDX-License-Identifier: Apache-2.0
"""The alignment's record from the sequencer's statuses (``fiber_align.alignment.record``)."""

import math

from fiber_align.alignment.record import AlignmentLog, RunRecord, RunTally


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


def test_counted_times_and_a_switch_cycle():
    """Counted in periods as bringup counts; a switch on starts a row; the part from status."""
    log = AlignmentLog('run', reference_power_w=1e-3, period_s=1e-3)
    got = log.on_status(st('SEARCHING', 0.099, sample=100, align_sample=100, part_id='A'))
    got += log.on_status(st('PEAKING', 0.139, sample=141, align_sample=100, part_id='B'))
    got += log.on_status(st('TRACKING', 0.199, sample=201, align_sample=100, part_id='B'))
    got += log.on_status(st('RELEASING', 0.5, sample=501, align_sample=100, part_id='B'))
    got += log.on_status(st('PEAKING', 0.6, sample=600, align_sample=100, part_id='B'))
    got += log.on_status(st('TRACKING', 0.65, sample=651, align_sample=100, part_id='C'))
    got += log.close()
    assert [(r['seq'], r['part_id']) for r in got] == [(1, 'A'), (2, 'B')]
    assert math.isclose(got[0]['time_to_first_light_s'], 0.040)
    assert math.isclose(got[0]['time_to_peak_s'], 0.100)
    assert got[1]['time_to_first_light_s'] == 0.0
    assert math.isclose(got[1]['time_to_peak_s'], 0.050)
    assert got[0]['samples'] == 401


def test_run_tally_from_diagnostics():
    """Cycles kept: the fewest of the plants (missed ones off); trips: summed per driver."""
    t = RunTally()
    assert t.figures() == dict(cycles_kept=None, watchdog_trips=None)
    t.on_status('/rig/x/simulated_actuator', {'sim_time_s': '1.0', 'sample': '1000',
                                              'missed_cycles': '3'})
    t.on_status('/rig/y/simulated_actuator', {'sim_time_s': '1.0', 'sample': '1001'})
    t.on_status('/rig/x/actuator_driver', {'watchdog_count': '1'})
    t.on_status('/rig/x/actuator_driver', {'watchdog_count': '2'})
    t.on_status('/rig/y/actuator_driver', {'watchdog_count': '1'})
    t.on_status('/rig/alignment_sequencer_2d', {'state': 'TRACKING'})
    assert t.figures() == dict(cycles_kept=997, watchdog_trips=3)


def test_the_end_power_is_the_status_one():
    """Readings that overtake the ending status (the fiber parking) do not set the loss."""
    log = AlignmentLog('run', reference_power_w=1e-3)
    log.on_status(st('SEARCHING', 0.0))
    log.on_power(1e-3 * 10 ** -0.005)
    log.on_status(st('TRACKING', 0.1, power_w=1e-3 * 10 ** -0.005))
    log.on_power(1e-9)                      # after the release, before its status
    row, = log.on_status(st('RELEASING', 0.2, power_w=1e-3 * 10 ** -0.003))
    assert math.isclose(row['final_loss_db'], 0.03)


def test_run_record_rows_at_start_and_end():
    """The run's row at its start, its end figures and the open alignment at its end."""
    rec = RunRecord(dict(machine='rig', sync_mode='lockstep', hardware=False, bag_path='',
                         graph_parameters='{"/rig/x/simulated_actuator": {"seed": 2}}',
                         reference_power_w=1e-3), 1e-3)
    first = rec.start_row()
    assert first['ended_at'] is None and first['machine'] == 'rig' and first['bag_path'] is None
    assert '"seed": 2' in first['parameters']
    assert rec.on_status('not json') == []
    rec.on_status('{"state": "SEARCHING", "sample": 10, "align_sample": 10, "part_id": "Q"}')
    rec.tally.on_status('/rig/x/simulated_actuator', {'sim_time_s': '1', 'sample': '900'})
    end = rec.end_rows()
    assert [t for t, _ in end] == ['alignments', 'runs']
    assert end[0][1]['part_id'] == 'Q' and end[0][1]['final_state'] == 'SEARCHING'
    run = end[1][1]
    assert run['run_id'] == first['run_id'] and run['started_at'] == first['started_at']
    assert run['cycles_kept'] == 900 and run['end_reason'] == 'stopped; sequencer SEARCHING'


def test_the_peak_power_from_the_statuses_after_the_opening_one():
    """On the graph no reading is taken: the peak is the highest of the statuses' peaks."""
    log = AlignmentLog('run', reference_power_w=1e-3)
    log.on_status(st('SEARCHING', 0.0, power_w=5e-3, peak_power_w=5e-3))   # before it
    log.on_status(st('PEAKING', 0.1, power_w=1e-5, peak_power_w=2e-5))
    log.on_status(st('TRACKING', 0.2, power_w=9e-4, peak_power_w=9.5e-4))
    log.on_status(st('HELD', 0.3, power_w=8e-4, peak_power_w=float('nan')))
    row, = log.on_status(st('RELEASING', 0.4, power_w=9e-4, peak_power_w=9.7e-4))
    assert row['peak_power_w'] == 9.7e-4
    log.on_status(st('SEARCHING', 1.0, power_w=1e-9, peak_power_w=9e-4))    # the parking
    row, = log.on_status(st('FAULT', 2.0, fault='no light', peak_power_w=None))
    assert row['peak_power_w'] is None
