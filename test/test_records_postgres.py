# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue on a PostgreSQL server of the tests' own (``test/pg_cluster.py``).

The same rows give the same records, selections and report as on SQLite; two writers at
once (two stations) lose and double nothing; a server stopped for 10 s in the middle of
the writes gets every row after its restart, once, and ``put`` never waited; a refused
URL and a newer schema are one line each while the caller goes on.
"""

import time

import pytest

from fiber_align.config import load_params
from fiber_align.records import backends, query, report, rows
from fiber_align.records.schema import CatalogError
from fiber_align.records.writer import CatalogWriter
from pg_cluster import free_port

pytestmark = [pytest.mark.ros, pytest.mark.postgres]


def params(tmp_path, name='spool', **over):
    """Return the writer's parameters with a spool of its own and fast retries."""
    p = load_params('records.yaml', 'run_catalog')
    p.update(spool_dir=str(tmp_path / name), retry_period_s=0.2, connect_timeout_s=1.0)
    p.update(over)
    return p


def station_rows(run_id, machine, n, part_of=lambda k: 'P%03d' % k, t0=1.8e9):
    """Return a run row and ``n`` alignment rows with varied figures (SI, dB)."""
    run = rows.run_row(run_id, machine, 'realtime', False, {'rate_hz': 1000.0},
                       rows.stamp(t0), rows.stamp(t0 + n), cycles_kept=1000 * n,
                       watchdog_trips=0, end_reason='stopped')
    aligns = [rows.alignment_row(
        run_id, k, part_of(k), rows.stamp(t0 + k), rows.stamp(t0 + k + 0.5),
        'FAULT' if k % 7 == 0 else 'TRACKING', {'loss_per_channel_db': [0.01 * k, 0.02]},
        fault_reason='lost light' if k % 7 == 0 else None,
        final_loss_db=None if k % 7 == 0 else 0.05 + 0.01 * (k % 5),
        time_to_peak_s=0.08 + 1e-3 * k, time_to_first_light_s=0.04, peak_power_w=1e-3,
        samples=80 + k) for k in range(1, n + 1)]
    return [('runs', run)] + [('alignments', a) for a in aligns]


def write_all(url, tmp_path, items, name='spool'):
    """Write ``items`` through a writer; return its final state."""
    w = CatalogWriter(url, params(tmp_path, name))
    for item in items:
        w.put(*item)
    assert w.flush(20.0), w.state()
    return w.close()


def test_the_same_records_on_sqlite_and_postgresql(tmp_path, pg_url):
    """Rows, selections and the report's figures are equal on both backends."""
    items = station_rows('run-a', 'station', 20) + station_rows('run-b', 'rig', 12, t0=1.9e9)
    sqlite_url = str(tmp_path / 'c.db')
    for url, name in ((sqlite_url, 's1'), (pg_url, 's2')):
        assert write_all(url, tmp_path, items, name)['written'] == len(items)
    dbs = [backends.connect(sqlite_url), backends.connect(pg_url)]
    try:
        assert dbs[1].dialect == 'postgresql'
        for f in (query.Filters(), query.Filters(machine='rig'), query.Filters(part='P003'),
                  query.Filters(state='FAULT'), query.Filters(since='2027-01-15',
                                                              until='2030-01-01')):
            a, b = (query.alignments(db, f) for db in dbs)
            assert a == b and a, f
            assert query.runs(dbs[0], f) == query.runs(dbs[1], f)
        assert query.run(dbs[0], 'run-b') == query.run(dbs[1], 'run-b')
        assert query.run(dbs[1], 'run-b')[0]['hardware'] is False
        ra, rb = (report.summary(query.columns(db), 0.08) for db in dbs)
        assert ra == rb and ra['all']['n'] == 32
    finally:
        for db in dbs:
            db.close()


def test_two_stations_writing_at_once(tmp_path, pg_url):
    """Two writers (two stations' catalogue writers), 20 alignments each: 40 rows."""
    writers = [CatalogWriter(pg_url, params(tmp_path, 'st%d' % i)) for i in (1, 2)]
    streams = [station_rows('station-%d' % i, 'station', 20) for i in (1, 2)]
    for a, b in zip(*streams):          # interleaved, as two graphs write
        writers[0].put(*a)
        writers[1].put(*b)
    for w in writers:
        assert w.flush(20.0), w.state()
        assert w.close()['written'] == 21
    db = backends.connect(pg_url)
    try:
        got = db.query('SELECT run_id, COUNT(*), COUNT(DISTINCT seq) FROM alignments '
                       'GROUP BY run_id ORDER BY run_id')[0]
        assert got == [('station-1', 20, 20), ('station-2', 20, 20)]
    finally:
        db.close()


def test_a_server_stopped_for_10_s_mid_write_loses_and_doubles_nothing(tmp_path, pg_server):
    """Rows keep coming while the server is down 10 s; all arrive after its restart, once."""
    url = pg_server.create_database('outage')
    w = CatalogWriter(url, params(tmp_path))
    items = station_rows('outage-run', 'station', 600)
    worst, states, stopped_at, restarted = 0.0, set(), None, False
    t0 = time.monotonic()
    for i, item in enumerate(items):      # 600 rows at 40 Hz: 15 s
        t = time.perf_counter()
        w.put(*item)
        worst = max(worst, time.perf_counter() - t)
        now = time.monotonic() - t0
        if stopped_at is None and now > 2.0:
            pg_server.stop('immediate')
            stopped_at = time.monotonic()
        if stopped_at and not restarted and time.monotonic() - stopped_at >= 10.0:
            pg_server.start()
            restarted = True
        states.add(w.state()['level'])
        time.sleep(max(0.0, (i + 1) / 40.0 - (time.monotonic() - t0)))
    if not restarted:
        pg_server.start()
    assert 'spooling' in states and 'ok' in states
    assert w.flush(30.0), w.state()
    s = w.close()
    assert s['dropped'] == 0 and s['level'] == 'ok'
    assert worst < 0.02, worst          # a put is a queue put, never a connection attempt
    db = backends.connect(url)
    try:
        got = db.query('SELECT COUNT(*), COUNT(DISTINCT seq), MIN(seq), MAX(seq) FROM '
                       'alignments')[0]
        assert got == [(600, 600, 1, 600)]
        assert db.query('SELECT COUNT(*) FROM runs')[0] == [(1,)]
    finally:
        db.close()


def test_a_refused_url_is_one_line_and_the_caller_runs_on(tmp_path):
    """Nobody listens: one line naming the catalogue (no password); puts return at once."""
    url = 'postgresql://fa:secret@127.0.0.1:%d/none' % free_port()
    with pytest.raises(CatalogError) as err:
        backends.connect(url, connect_timeout_s=1.0)
    text = str(err.value)
    assert '\n' not in text and 'cannot connect' in text and 'secret' not in text
    w = CatalogWriter(url, params(tmp_path))
    t = time.perf_counter()
    for item in station_rows('r', 'rig', 5):
        assert w.put(*item)
    assert time.perf_counter() - t < 0.05
    s = w.close(3.0)
    assert s['level'] == 'spooling' and s['spooled'] == 6 and 'cannot connect' in s['reason']


def test_a_newer_schema_on_postgresql_is_refused(pg_url):
    """The newer catalogue is one line and left as it is."""
    db = backends.connect(pg_url)
    db.run_statements(['UPDATE catalog_schema SET version = 9'])
    db.close()
    with pytest.raises(CatalogError) as err:
        backends.connect(pg_url)
    assert 'version 9' in str(err.value) and '\n' not in str(err.value)
