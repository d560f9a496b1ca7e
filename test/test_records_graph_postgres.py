# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue on PostgreSQL, written by running graphs (docs/records.md).

The server is the tests' own (``test/pg_cluster.py``: ``initdb`` and ``pg_ctl`` in a
temporary folder, a loopback port), each test a new database on it. ``bringup`` runs the
graphs with ``--catalog postgresql://...``, as a line of stations would: the rows equal
the run's summary, as on SQLite; two stations in two namespaces write at once, none lost
or doubled; the server stopped for 10 s in a realtime run: the rows of that time arrive
after its restart, and the loop keeps its periods as a run without the catalogue does.
"""

import json
import os
import subprocess
import sys
import time

import pytest

from fiber_align.records import backends
from procs import run_bounded, stop
from test_records_graph import assert_five_parts

pytestmark = [pytest.mark.ros, pytest.mark.postgres]


def _bringup_cmd(summary, *options):
    # not --quiet: the catalogue's WARN is relayed into the log
    return [sys.executable, '-m', 'fiber_align.bringup', *options, '--summary',
            str(summary)]


def _summary(path):
    return json.loads(path.read_text(encoding='utf-8')) if path.exists() else {}


def _query(url, sql):
    db = backends.connect(url)
    try:
        rows, cols = db.query(sql)
        return [dict(zip(cols, r)) for r in rows]
    finally:
        db.close()


def _alignments(url):
    return _query(url, 'SELECT * FROM alignments ORDER BY run_id, seq')


def test_a_rig_run_writes_the_rows_its_summary_reports(tmp_path, pg_url):
    """
    The lockstep rig, 5 alignments a part each, on PostgreSQL: the rows equal the summary.

    The same checks as on SQLite (``test_records_graph.py``); two runs of the rig are not
    compared with each other: bringup asks for each alignment at a sample of its own.
    """
    summary = tmp_path / 'summary.json'
    code, out = run_bounded(_bringup_cmd(summary, '--rig', '--sync', 'lockstep', '--seed',
                                         '1', '--cycles', '4', '--part', 'P', '--catalog',
                                         pg_url), 240)
    assert code == 0, out
    s = _summary(summary)
    runs = _query(pg_url, 'SELECT * FROM runs')
    assert len(runs) == 1, runs
    r = runs[0]
    assert (r['machine'], r['sync_mode'], bool(r['hardware'])) == ('rig', 'lockstep', False)
    assert r['ended_at'] > r['started_at'] and r['end_reason'].startswith('stopped'), r
    assert json.loads(r['parameters'])['/rig/alignment_sequencer_2d']['machine'] == 'rig'
    assert_five_parts(_alignments(pg_url), s)


def test_two_graphs_in_two_namespaces_write_at_once(tmp_path, pg_url):
    """
    Two stations (``/line1``, ``/line2``) align 20 times each, at once: 40 rows, once each.

    In lockstep: two realtime stations overload this machine's two cores (0.55 % of the
    periods missed each, one alignment in three pairs ended in FAULT); a lockstep
    station's 20 alignments take about a minute of a core (59 s alone here).
    """
    procs, logs = [], []
    try:
        for k in (1, 2):
            log = open(tmp_path / ('line%d.log' % k), 'w')
            logs.append(log)
            procs.append(subprocess.Popen(
                _bringup_cmd(tmp_path / ('line%d.json' % k), '--station', '--namespace',
                             'line%d' % k, '--sync', 'lockstep', '--seed', str(k),
                             '--cycles', '19', '--part', 'L%d' % k, '--catalog', pg_url),
                env=dict(os.environ), stdout=log, stderr=subprocess.STDOUT))
        codes = [p.wait(timeout=500) for p in procs]
    finally:
        for p in procs:
            stop(p, 10.0)
        for log in logs:
            log.close()
    # a failure names each run's error and its log's last lines (pytest cuts a long repr)
    outs = ['line%d: exit %s, error %r\n%s' % (
        k, code, _summary(tmp_path / ('line%d.json' % k)).get('error'),
        '\n'.join((tmp_path / ('line%d.log' % k)).read_text().splitlines()[-25:]))
        for k, code in zip((1, 2), codes)]
    assert codes == [0, 0], '\n'.join(outs)
    runs = _query(pg_url, 'SELECT run_id, parameters, machine, sync_mode FROM runs')
    assert len(runs) == 2, runs
    assert {(r['machine'], r['sync_mode']) for r in runs} == {('station', 'lockstep')}, runs
    spaces = sorted({k.split('/')[1] for r in runs for k in json.loads(r['parameters'])
                     if k.startswith('/line')})
    assert spaces == ['line1', 'line2'], spaces
    rows = _alignments(pg_url)
    assert len(rows) == 40, [(a['run_id'][:8], a['seq']) for a in rows]
    assert len({(a['run_id'], a['seq']) for a in rows}) == 40
    for r in runs:
        mine = [a for a in rows if a['run_id'] == r['run_id']]
        assert [a['seq'] for a in mine] == list(range(1, 21))
        # a record never mixes two graphs' parts
        assert len({a['part_id'].split('-')[0] for a in mine}) == 1, mine
        assert all(a['final_state'] == 'TRACKING' for a in mine), [
            (a['seq'], a['final_state'], a.get('fault_reason')) for a in mine
            if a['final_state'] != 'TRACKING']


def _missed(summary):
    """
    Return the worst axis's missed share of a realtime run beyond the machine's floor.

    The floor is what the bare loop beside the run lost (bringup's own goal rule): the
    test's server restarts on this machine (its crash recovery takes the cores a
    server elsewhere would not), and that is the machine's load, not the catalogue's.
    """
    shares = [a.get('realtime', a).get('missed_share')
              for a in (summary.get('axes') or {}).values() if isinstance(a, dict)]
    shares = [x for x in shares if x is not None]
    floor = (summary.get('floor') or {}).get('lost_share') or 0.0
    return max(shares) - floor if shares else None


def test_a_server_stopped_for_10_s_in_a_realtime_run(tmp_path, pg_server):
    """
    The server is down 10 s from the first alignment: its rows arrive after the restart.

    The catalogue's writer is a process of its own; the loop keeps its periods as the
    same run without a catalogue, beside the same outage, does in the same test.
    """
    url = pg_server.create_database('outage_graph')
    figures = {}
    for case in ('none', 'outage'):
        summary = tmp_path / ('%s.json' % case)
        log = tmp_path / ('%s.log' % case)
        with open(log, 'w') as f:
            proc = subprocess.Popen(_bringup_cmd(
                summary, '--rig', '--sync', 'realtime', '--seed', '2', '--cycles', '20',
                '--duration', '14', '--catalog', url if case == 'outage' else 'none'),
                env=dict(os.environ), stdout=f, stderr=subprocess.STDOUT)
        down = False
        try:
            # both runs meet the same outage, 10 s from their first alignment: the server's
            # crash recovery at its restart loads this machine's two cores whether or not
            # the graph writes to it (a server of a real line runs elsewhere); what differs
            # is the catalogue alone
            end = time.monotonic() + 90.0
            while time.monotonic() < end and proc.poll() is None and \
                    'state SEARCHING' not in log.read_text(errors='replace'):
                time.sleep(0.05)
            assert proc.poll() is None, log.read_text()[-3000:]
            pg_server.stop('immediate')
            down = True
            time.sleep(10.0)
            pg_server.start()
            down = False
            proc.wait(timeout=240)
        finally:
            stop(proc, 10.0)
            if down:
                pg_server.start()
        s = _summary(summary)
        assert proc.returncode == 0 and s.get('state') == 'TRACKING', log.read_text()[-3000:]
        figures[case] = s
    out = (tmp_path / 'outage.log').read_text()
    # the outage said on /diagnostics (the relayed WARN), and the rows all there, once
    assert 'rows wait in' in out or 'spool' in out, out[-3000:]
    rows = _alignments(url)
    assert [a['seq'] for a in rows] == list(range(1, 22)), rows
    assert all(a['final_state'] == 'TRACKING' for a in rows)
    runs = _query(url, 'SELECT run_id, ended_at, end_reason FROM runs')
    assert len(runs) == 1 and runs[0]['ended_at'], runs
    # no period missed because of the catalogue: as many kept beyond the machine's floor
    # as without it (a loaded machine's run-to-run spread: 0.1 % of the periods)
    missed = {k: _missed(v) for k, v in figures.items()}
    print('missed beyond the floor: %s; floors %s' % (missed, {
        k: (v.get('floor') or {}).get('lost_share') for k, v in figures.items()}))
    assert None not in missed.values(), figures
    assert missed['outage'] <= missed['none'] + 1e-3, missed
