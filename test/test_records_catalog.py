# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue on SQLite (pure: no process): schema, migration, writer, bad inputs.

PostgreSQL's side of the same properties is ``test_records_postgres.py``.
"""

import json
import sqlite3
import threading
import time

import pytest

from fiber_align.config import load_params
from fiber_align.records import backends, query, rows, schema
from fiber_align.records.schema import CatalogError
from fiber_align.records.writer import CatalogWriter


def params(tmp_path, **over):
    """Return the writer's parameters with a spool in ``tmp_path`` and fast retries."""
    p = load_params('records.yaml', 'run_catalog')
    p.update(spool_dir=str(tmp_path / 'spool'), retry_period_s=0.05, busy_timeout_s=0.05)
    p.update(over)
    return p


def some_rows(run_id, n, part='P1'):
    """Return a run row and ``n`` alignment rows (``seq`` 1..n)."""
    t = rows.stamp()
    run = rows.run_row(run_id, 'rig', 'lockstep', False, {'rate_hz': 1000.0}, t)
    aligns = [rows.alignment_row(run_id, k, part, t, t, 'TRACKING', {'k': k},
                                 final_loss_db=0.01 * k, time_to_peak_s=0.1 + k * 1e-3,
                                 samples=100 + k) for k in range(1, n + 1)]
    return run, aligns


def test_default_catalogue_lives_under_ros_home(tmp_path):
    """``default`` is ``$ROS_HOME/fiber_align/catalog.db``, ``~/.ros`` without ROS_HOME."""
    env = {'ROS_HOME': str(tmp_path / 'rh')}
    assert backends.parse('default', env) == ('sqlite', tmp_path / 'rh' / 'fiber_align' /
                                              'catalog.db')
    home = backends.parse('default', {'HOME': '/x'})[1]
    assert home.parts[-3:] == ('.ros', 'fiber_align', 'catalog.db')
    assert backends.parse('none') is None and backends.parse('NONE') is None
    assert backends.parse('postgresql://u:secret@h:5/db')[0] == 'postgresql'
    assert 'secret' not in backends.describe('postgresql://u:secret@h:5/db')
    db = backends.connect('default', env)      # creates the folder of the default only
    assert (tmp_path / 'rh' / 'fiber_align' / 'catalog.db').is_file()
    assert db.version() == schema.SCHEMA_VERSION
    db.close()


def test_a_version_1_catalogue_is_migrated_with_its_rows(tmp_path):
    """An old catalogue (version 1) gains version 2's column; its rows stay."""
    path = tmp_path / 'old.db'
    conn = sqlite3.connect(str(path))
    for s in schema.create_v1('sqlite'):
        conn.execute(s)
    conn.execute("INSERT INTO runs (run_id, machine) VALUES ('r1', '1d')")
    conn.execute("INSERT INTO alignments (run_id, seq, part_id, final_loss_db) VALUES "
                 "('r1', 1, 'P', 0.5)")
    conn.commit()
    conn.close()
    db = backends.connect(str(path))
    assert db.version() == 2
    run, aligns = query.run(db, 'r1')
    assert run['machine'] == '1d' and run['snapshot_paths'] is None
    assert [(a['part_id'], a['final_loss_db']) for a in aligns] == [('P', 0.5)]
    db.close()


def test_a_newer_catalogue_is_refused_in_one_line(tmp_path):
    """A catalogue of a newer schema: one line naming both versions; it is left as it is."""
    path = tmp_path / 'new.db'
    db = backends.connect(str(path))
    db.run_statements(['UPDATE catalog_schema SET version = 7'])
    db.close()
    with pytest.raises(CatalogError) as err:
        backends.connect(str(path))
    text = str(err.value)
    assert '\n' not in text and 'version 7' in text and 'newer' in text
    assert sqlite3.connect(str(path)).execute(
        'SELECT version FROM catalog_schema').fetchone() == (7,)


def test_writes_are_idempotent_and_a_run_is_completed_at_its_end(tmp_path):
    """The same alignment twice is one row; a run's end row keeps its start's columns."""
    db = backends.connect(str(tmp_path / 'c.db'))
    run, aligns = some_rows('r1', 3)
    db.write([('runs', run)] + [('alignments', a) for a in aligns])
    db.write([('alignments', a) for a in aligns])           # a spool replayed
    end = dict(run, machine=None, ended_at=rows.stamp(), end_reason='stopped',
               cycles_kept=1234)
    db.write([('runs', end)])
    got, al = query.run(db, 'r1')
    assert len(al) == 3 and [a['seq'] for a in al] == [1, 2, 3]
    assert got['machine'] == 'rig' and got['end_reason'] == 'stopped'
    assert got['cycles_kept'] == 1234 and got['hardware'] is False
    assert got['parameters'] == {'rate_hz': 1000.0}
    db.close()


def test_the_writer_spools_while_the_file_is_locked_and_writes_once_after(tmp_path):
    """A locked SQLite file: put() never waits, rows spool, then arrive once, none lost."""
    path = tmp_path / 'c.db'
    backends.connect(str(path)).close()
    w = CatalogWriter(str(path), params(tmp_path))
    assert w.flush(5.0)
    lock = sqlite3.connect(str(path), timeout=0)
    lock.execute('BEGIN EXCLUSIVE')         # another process holds the file
    run, aligns = some_rows('r1', 50)
    worst = 0.0
    for r in [('runs', run)] + [('alignments', a) for a in aligns]:
        t0 = time.perf_counter()
        w.put(*r)
        worst = max(worst, time.perf_counter() - t0)
        time.sleep(0.002)
    t_end = time.monotonic() + 5.0
    while w.state()['level'] != 'spooling' and time.monotonic() < t_end:
        time.sleep(0.01)
    s = w.state()
    assert s['level'] == 'spooling' and 'locked' in s['reason'], s
    assert w.spool.is_file()
    lock.rollback()
    lock.close()
    assert w.flush(10.0), w.state()
    s = w.close()
    assert s['level'] == 'ok' and s['dropped'] == 0 and s['written'] == 51
    assert worst < 0.01, worst      # a queue put: never the database's lock wait (0.05 s)
    db = backends.connect(str(path))
    assert db.query('SELECT COUNT(*), COUNT(DISTINCT seq) FROM alignments')[0] == [(50, 50)]
    assert not w.spool.exists()
    db.close()


def test_a_spool_left_by_a_stopped_writer_is_written_by_the_next(tmp_path):
    """Rows that waited when a writer stopped arrive with the next writer: once."""
    folder = tmp_path / 'later'
    url = str(folder / 'c.db')
    w = CatalogWriter(url, params(tmp_path))     # its folder is missing: it spools
    run, aligns = some_rows('r1', 5)
    for r in [('runs', run)] + [('alignments', a) for a in aligns]:
        w.put(*r)
    assert not w.flush(0.5)
    # a try that fails during the wait ends it: the rows are in the spool, the CLI's
    # end does not wait its 10 s for a folder that will not appear
    w.retry_period_s = 0.3
    t0 = time.monotonic()
    assert not w.flush(10.0, until_refused=True)
    assert time.monotonic() - t0 < 5.0, time.monotonic() - t0    # half its bound
    s = w.close()
    assert s['level'] == 'spooling' and s['spooled'] == 6 and 'does not exist' in s['reason']
    folder.mkdir()
    w2 = CatalogWriter(url, params(tmp_path))
    assert w2.flush(5.0), w2.state()
    w2.close()
    db = backends.connect(url)
    assert db.query('SELECT COUNT(*) FROM alignments')[0] == [(5,)]
    db.close()


@pytest.mark.parametrize('where', ['missing', 'refuses'])
def test_a_bad_path_is_one_line_and_the_caller_runs_on(tmp_path, where):
    """A folder that is missing or takes no files: one line; puts go on without waiting."""
    url = str(tmp_path / 'no' / 'c.db') if where == 'missing' else '/proc/fa_catalog.db'
    with pytest.raises(CatalogError) as err:
        backends.connect(url)
    assert '\n' not in str(err.value) and url in str(err.value)
    w = CatalogWriter(url, params(tmp_path))
    run, aligns = some_rows('r1', 3)
    t0 = time.perf_counter()
    for r in [('runs', run)] + [('alignments', a) for a in aligns]:
        assert w.put(*r)
    assert time.perf_counter() - t0 < 0.05
    s = w.close(2.0)
    assert s['level'] == 'spooling' and s['spooled'] == 4 and '\n' not in s['reason']
    assert url in s['reason']


def test_a_full_queue_drops_counted_rather_than_waits(tmp_path):
    """A writer that cannot keep up (held here): put() returns at once, drops are counted."""
    gate = threading.Event()

    def slow_connect(url, **kw):
        gate.wait(5.0)
        return backends.connect(url, **kw)
    w = CatalogWriter(str(tmp_path / 'c.db'), params(tmp_path, queue_size=4),
                      connect=slow_connect)
    run, aligns = some_rows('r1', 10)
    t0 = time.perf_counter()
    took = [w.put('alignments', a) for a in aligns]
    assert time.perf_counter() - t0 < 0.05
    assert took.count(False) == 6 and w.state()['dropped'] == 6
    assert 'queue full' in w.state()['reason']
    gate.set()
    w.close()


def test_off_writes_nothing(tmp_path):
    """``none``: no thread, no file, puts are ignored."""
    w = CatalogWriter('none', params(tmp_path))
    assert w.put('runs', {'run_id': 'x'}) is False
    assert w.close()['level'] == 'off' and not (tmp_path / 'spool').exists()


def test_rows_of_a_switch_scenario():
    """The alignment is seq 1 (its figures as columns); one row per switch cycle after it."""
    res = {'state': 'TRACKING', 'final_loss_db': 0.007, 'time_to_peak_s': 0.079,
           'time_to_first_light_s': 0.043, 'samples': 79, 'slot_m': 4e-5,
           'cycle_loss_db': [0.01, 0.02, 0.03], 'switch_faults': ['cycle 2: FAULT lost']}
    got = rows.alignment_rows(res, 'r', 'P', 'a', 'b')
    assert [r['seq'] for r in got] == [1, 2, 3, 4]
    assert got[0]['final_loss_db'] == 0.007 and got[0]['samples'] == 79
    assert json.loads(got[0]['figures'])['slot_m'] == 4e-5
    assert [r['final_loss_db'] for r in got[1:]] == [0.01, 0.02, 0.03]
    assert [r['final_state'] for r in got[1:]] == ['TRACKING', 'TRACKING', 'FAULT']
    assert {r['part_id'] for r in got} == {'P'}


def test_the_catalogue_never_imports_ros():
    """The catalogue is pure: nodes and tools use it, it imports no rclpy nor a ROS message."""
    import ast
    from pathlib import Path
    import fiber_align.records
    found = []
    for path in Path(fiber_align.records.__file__).parent.glob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ''] if isinstance(node, ast.ImportFrom) else []
            found += ['%s: %s' % (path.name, n) for n in names
                      if n.split('.')[0] in ('rclpy', 'std_msgs', 'diagnostic_msgs')]
    assert not found, found
