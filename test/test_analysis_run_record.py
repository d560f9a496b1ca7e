# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.analysis.run_record`: bringup's per-sample record, pure."""

import json
import time
from types import SimpleNamespace

import numpy as np

from fiber_align.analysis.bag.writer import write_bag
from fiber_align.analysis.run_record import DiagnosticsRecord, record_from_bag, RunRecord
from fiber_align.simulation.setpoints import Source


def record(lockstep=False, done_ago=None, own_done=False, **kw):
    rec = RunRecord({'y': None}, lockstep=lockstep, **kw)
    if own_done:
        rec.done.set()
    rec.runner_done_at = None if done_ago is None else time.monotonic() - done_ago
    return rec


# A realtime run ends ``observer_drain_s`` after the runner's done, however far behind.
def test_behind_once_the_runner_is_done_longer_than_the_drain():
    assert record(done_ago=2.5).behind(2.0)
    assert not record(done_ago=1.0).behind(2.0)


def test_not_behind_before_the_runner_is_done_or_once_the_record_is_complete():
    assert not record(done_ago=None).behind(2.0)
    assert not record(done_ago=5.0, own_done=True).behind(2.0)


def test_lockstep_always_waits_for_its_own_record():
    # lockstep figures are compared sample for sample: its record must be whole
    assert not record(lockstep=True, done_ago=60.0).behind(2.0)


def test_lockstep_samples_sit_on_the_period_grid_and_end_at_the_duration():
    rec = RunRecord({'y': None, 'v': None}, clock='y', lockstep=True, rate_hz=1000.0,
                    duration_s=0.003)
    rec.add('y', 1.0, 5_000_000)            # before start(): not recorded
    assert rec.samples == 0
    rec.active = True
    for i, ns in enumerate((7_000_000, 8_000_100, 8_999_900, 10_000_000)):
        rec.add('y', float(i), ns)
        rec.add('v', 10.0 * i)
    t, r, y = rec.trace()
    assert np.allclose(t, [0.0, 0.001, 0.002]) and rec.done.is_set()
    assert list(y) == [0.0, 1.0, 2.0] and np.isnan(r).all()
    assert list(rec.series('v')) == [0.0, 10.0, 20.0]      # cut to the samples


def test_a_state_holds_from_the_sample_after_the_one_the_sequencer_stepped():
    rec = RunRecord({'y': None}, clock='y', lockstep=True, rate_hz=1000.0)
    rec.active = True
    rec.add('y', 0.0, 2_000_000_000)
    rec.add_state(json.dumps({'state': 'SEARCHING', 'sample_time_s': 2.004}))
    rec.add_state('IDLE')                   # a bare name: from the samples so far
    assert rec.first('SEARCHING') == (5, {'state': 'SEARCHING', 'sample_time_s': 2.004})
    assert rec.first('IDLE')[0] == 1 and rec.status == {'state': 'IDLE'}
    assert rec.first('TRACKING') == (None, None)


def test_without_a_clock_a_state_holds_from_its_own_sample():
    rec = RunRecord({'a': None, 'b': None})
    rec.add('a', 1.0)
    rec.add('a', 2.0)
    rec.add('b', 3.0)
    rec.add_state(json.dumps({'state': 'PEAKING', 'sample': 42}))
    assert rec.samples == 1 and rec.first('PEAKING')[0] == 42
    assert list(rec.series('a')) == [1.0]      # the complete samples only


def test_a_stream_short_of_the_clock_is_padded_with_nan():
    rec = RunRecord({'y': None, 'v': None}, clock='y', rate_hz=1000.0)
    rec.active = True
    rec.add('v', 5.0)
    for ns in (0, 1_000_000, 2_000_000):
        rec.add('y', 0.0, ns)
    v = rec.series('v')
    assert v[0] == 5.0 and np.isnan(v[1:]).all() and v.size == 3
    cols = rec.columns(['y', 'v'])
    assert list(cols) == ['y', 'v'] and np.array_equal(cols['v'], v, equal_nan=True)


def status(name, level=0, message='', **values):
    return SimpleNamespace(name=name, level=bytes([level]), message=message, values=[
        SimpleNamespace(key=k, value=str(v)) for k, v in values.items()])


def test_diagnostics_keep_the_newest_distinct_errors_and_the_worst_window_inside_the_run():
    d = DiagnosticsRecord()
    d.add(status('/rig/x/simulated_actuator', **{'cycle.achieved_rate_hz': 900}), 0.0)
    assert d.latest['simulated_actuator']['_t'] == 0.0 and not d.worst   # no run yet
    d.run_from, d.run_to = 10.0, 20.0
    for now, rate in ((10.5, 800), (10.7, 950), (12.0, 990), (21.0, 100)):
        d.add(status('/rig/x/simulated_actuator', **{'cycle.achieved_rate_hz': rate}), now)
    # the report at 10.5 s covers a window that began before the run: not counted
    assert d.worst['simulated_actuator'] == {'windows': 2, 'rate_min_hz': 950.0}
    assert d.by_status['worst']['/rig/x/simulated_actuator']['windows'] == 2
    for msg in ('amplifier lost', 'amplifier lost', 'watchdog'):
        d.add(status('/actuator_driver', 2, msg), 15.0)
    assert d.errors == {'actuator_driver': ['amplifier lost', 'watchdog']}
    assert d.level('actuator_driver') == 2 and d.level('simulated_actuator') == 0
    assert d.level('power_meter') is None                       # no report yet


def test_a_command_caused_the_next_state_and_lockstep_align_counts_as_the_sequencer_does():
    rec = RunRecord({'y': None}, clock='y', lockstep=True)
    rec.add_state(json.dumps({'state': 'IDLE'}))
    rec.add_state(json.dumps({'state': 'SEARCHING', 'sample': 9, 'align_sample': 17}))
    assert rec.caused(1, 'align') == 17 and rec.caused(1, 'switch') == 0
    assert rec.caused(2, 'align', timeout_s=0.01) == 0         # none came: the samples
    free = RunRecord({'y': None}, clock='y')
    free.add_state(json.dumps({'state': 'SEARCHING', 'align_sample': 17}))
    assert free.caused(0, 'align') == 0                         # realtime: as it arrived


# A recorded realtime run's record is read from its bag, as the observer would record it.
def test_a_record_from_a_bag_keeps_the_samples_below_the_duration_and_the_drive_from_them(
        tmp_path):
    rate, n = 1000.0, 300
    t0 = 5_000_000_000
    stamps = t0 + np.arange(n, dtype=np.int64) * 1_000_000     # 1 kHz sample stamps, ns
    pos = 1e-6 * np.sin(np.arange(n) / 30.0)
    # the drive: two messages before the first sample (the driver's start), then one each
    v_t = np.concatenate([[t0 - 2_000_000, t0 - 1_000_000], stamps + 200_000])
    v = np.concatenate([[9.0, 9.0], 10.0 + np.arange(n)])
    bag = write_bag(tmp_path / 'bag', {
        'displacement': {'t_ns': stamps + 100_000, 'stamp_ns': stamps, 'position': pos},
        'drive_voltage': {'t_ns': v_t, 'data': v}})
    source = Source('sine')
    rec, error = record_from_bag(bag, source, rate, 0.2)
    t, r, y = rec.trace()
    assert error == ''
    # 0.2 s at 1 kHz: samples 0..199 (t < duration - half a period), timed by their stamps
    assert t.size == 200 and np.allclose(t, np.arange(200) / rate)
    assert np.array_equal(y, pos[:200])
    assert np.allclose(r, [source.value(x) for x in t])
    # the drive from the first sample on: the two before it are not the run's
    assert np.array_equal(rec.series('v'), 10.0 + np.arange(200))


def test_an_unreadable_bag_is_an_empty_record_and_its_reason(tmp_path):
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'metadata.yaml').write_text('not: a bag', encoding='utf-8')
    rec, error = record_from_bag(tmp_path / 'bag', None, 1000.0, 1.0)
    assert rec.samples == 0 and error, error
