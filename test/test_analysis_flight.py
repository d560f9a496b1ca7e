# SPDX-License-Identifier: Apache-2.0
"""The flight recorder's pure core: ring bounds, the window's cut, debouncing, naming, the bag."""

import json
import os

import numpy as np

from fiber_align.analysis.bag import FLOAT64, read_streams
from fiber_align.analysis.bag.cdr import encode_float64
from fiber_align.analysis.bag.flight import (ENTRY_OVERHEAD_BYTES, FlightRecorder, Ring,
                                             slug, snapshot_name, Triggers)

S = 1_000_000_000
T0 = 1_700_000_000 * S


def test_the_ring_keeps_its_horizon_and_its_bytes():
    ring = Ring(horizon_s=1.0, max_bytes=10 ** 9)
    for k in range(3000):                   # 3 s at 1 kHz
        ring.append(T0 + k * S // 1000, b'12345678')
    ts = [t for t, _ in ring.entries]
    assert ts[-1] - ts[0] <= S and len(ts) == 1001
    assert ring.bytes == len(ts) * (8 + ENTRY_OVERHEAD_BYTES)
    small = Ring(horizon_s=10.0, max_bytes=100 * (8 + ENTRY_OVERHEAD_BYTES))
    for k in range(3000):
        small.append(T0 + k * S // 1000, b'12345678')
    assert len(small.entries) == 100 and small.bytes <= small.max_bytes
    assert small.capped == 2900


def test_the_cut_is_the_window_and_the_bound_is_split_over_the_topics():
    now = [T0 + 20 * S]
    fr = FlightRecorder('/nonexistent', 10.0, 2.0, 64 * 2 ** 20, 4, clock=lambda: now[0],
                        thread=False)
    assert fr.topic_bytes == 16 * 2 ** 20 and fr.horizon_s == 13.0
    ring = fr.ring('/drive_voltage', FLOAT64)
    for k in range(20000):                  # 20 s at 1 kHz
        ring.append(T0 + k * S // 1000, b'x')
    snap = fr.trigger('service', T0 + 17 * S)
    cut = fr.cut(snap)['/drive_voltage'][1]
    assert cut[0][0] == T0 + 7 * S and cut[-1][0] == T0 + 19 * S
    assert len(cut) == 12001
    kept, bound = fr.memory()
    assert kept <= bound and kept == ring.bytes


def test_triggers_inside_a_window_are_counted_not_snapshots(tmp_path):
    fr = FlightRecorder(str(tmp_path), 10.0, 2.0, 2 ** 20, 1, clock=lambda: T0, thread=False)
    first = fr.trigger('sequencer FAULT', T0)
    assert first is not None
    assert fr.trigger('watchdog actuator_driver', T0 + S) is None
    assert fr.trigger('service', T0 + 2 * S) is None
    assert fr.absorbed == 2 and first.absorbed == ['watchdog actuator_driver', 'service']
    second = fr.trigger('service', T0 + 2 * S + 1)
    assert second is not None and second.lo_ns == T0 - 8 * S + 1
    assert len(fr.snapshots) == 2


def test_names_are_time_and_reason_and_never_taken(tmp_path):
    assert slug('sequencer FAULT') == 'sequencer-fault'
    assert slug('watchdog /x/actuator_driver') == 'watchdog-x-actuator-driver'
    assert slug('***') == 'trigger'
    name = snapshot_name(T0, 'service')
    assert len(name) == len('YYYYmmdd_HHMMSS_service') and name.endswith('_service')
    fr = FlightRecorder(str(tmp_path), 0.1, 0.1, 2 ** 20, 1, clock=lambda: T0, thread=False)
    os.makedirs(os.path.join(str(tmp_path), name))
    a = fr.trigger('service', T0)
    b = fr.trigger('service', T0 + S // 2)
    assert a.path.endswith(name + '_2') and b.path.endswith(name + '_3')


def test_a_snapshot_is_a_bag_analyze_reads(tmp_path):
    now = [T0 + 3 * S]
    written = []
    fr = FlightRecorder(str(tmp_path / 'snaps'), 1.0, 0.5, 2 ** 22, 2,
                        on_written=written.append, clock=lambda: now[0])
    disp = fr.ring('/drive_voltage', FLOAT64)
    rows = encode_float64(np.arange(3000) * 1e-9)
    for k in range(3000):                   # 3 s at 1 kHz
        disp.append(T0 + k * S // 1000, rows[k].tobytes())
    snap = fr.trigger('driver inactive', T0 + 2 * S)
    fr.close(10.0)                          # the stop writes it at once
    assert written == [snap] and snap.error is None, snap.error
    assert snap.counts == {'/drive_voltage': 1501}
    info = json.loads((tmp_path / 'snaps' / os.path.basename(snap.path) /
                       'snapshot.json').read_text())
    assert info['reason'] == 'driver inactive' and info['messages'] == snap.counts
    streams = read_streams(snap.path)[0]
    assert len(streams['drive_voltage'].t_ns) == 1501
    assert fr.state()['snapshots_written'] == 1


def test_a_snapshot_of_several_chunks_reads_each_topic_in_time_order(tmp_path):
    """
    Two topics over the same 60 s at 1 kHz, five chunks (1 MiB each): both read in order.

    Written topic after topic, a chunk held one topic's tail and the next one's head,
    started at the head's time, and was read before the first topic's middle: its
    stamps went backwards (the flight recorder test, 2026-12-06).
    """
    from fiber_align.analysis.bag.flight import write_snapshot
    n = 60000
    rows = encode_float64(np.arange(n) * 1e-9)
    # 120,000 records of 43 bytes: five chunks, the third the first topic's tail and the
    # second's head
    cuts = {t: (FLOAT64, [(T0 + k * S // 1000 + i, rows[k].tobytes()) for k in range(n)])
            for i, t in enumerate(('/drive_voltage', '/feedback_voltage'))}
    path = str(tmp_path / 'snap')
    assert write_snapshot(path, cuts) == {t: n for t in cuts}
    streams = read_streams(path)[0]
    for key in ('drive_voltage', 'feedback_voltage'):
        t = np.asarray(streams[key].t_ns, np.int64)
        assert t.size == n and (np.diff(t) > 0).all(), key


def test_triggers_are_edges():
    tr = Triggers()
    assert tr.on_state(json.dumps({'state': 'SEARCHING'})) is None
    assert tr.on_state(json.dumps({'state': 'FAULT'})) == 'sequencer FAULT'
    assert tr.on_state(json.dumps({'state': 'FAULT'})) is None
    assert tr.on_state(json.dumps({'state': 'HELD'})) == 'sequencer HELD'
    assert tr.on_state('not json') is None
    drv = '/actuator_driver'
    assert tr.on_status(drv, 0, 'ok', {'watchdog_count': '3'}) is None   # the baseline
    assert tr.on_status(drv, 0, 'ok', {'watchdog_count': '3'}) is None
    assert tr.on_status(drv, 1, 'ok', {'watchdog_count': '4'}) == 'watchdog actuator_driver'
    plant = '/simulated_actuator'
    warn = 'missed 2 % of the cycles in the last 10 s (goal <= 1 %)'
    assert tr.on_status(plant, 0, 'ok', {'sim_time_s': '1'}) is None
    assert tr.on_status(plant, 1, warn, {'sim_time_s': '2'}) == \
        'missed cycles simulated_actuator'
    assert tr.on_status(plant, 1, warn, {'sim_time_s': '3'}) is None
    assert tr.on_transition('actuator_driver', 'active', 'deactivating') == \
        'actuator_driver inactive'
    assert tr.on_transition('actuator_driver', 'deactivating', 'inactive') is None
    assert tr.on_transition('actuator_driver', 'inactive', 'activating') is None
