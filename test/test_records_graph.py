# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue on the graph (docs/records.md): ``run_catalog`` beside a running graph.

``bringup`` runs with the default catalogue (``$ROS_HOME`` is the test session's own,
``test/conftest.py``); ``sqlite3`` reads the file afterwards: the ``runs`` row (machine,
sync mode, the graph's parameters, its end figures) and an ``alignments`` row per
alignment, compared with the run's summary. Bad catalogues (a missing folder, a folder
that takes no files, a refused PostgreSQL URL, a newer schema): one line, the graph runs
on and ends as without a catalogue.
"""

import json
import os
import sqlite3
import sys

import pytest

from procs import run_bounded

pytestmark = [pytest.mark.ros]


def _bringup(tmp_path, *options, timeout=240):
    """Run bringup with ``ROS_HOME`` in ``tmp_path``; return (code, output, summary, db)."""
    home = tmp_path / 'ros_home'
    home.mkdir(exist_ok=True)
    summary = tmp_path / 'summary.json'
    old = os.environ.get('ROS_HOME')
    os.environ['ROS_HOME'] = str(home)
    try:
        code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', *options,
                                 '--summary', str(summary)], timeout)
    finally:
        os.environ['ROS_HOME'] = old
    s = json.loads(summary.read_text(encoding='utf-8')) if summary.exists() else {}
    return code, out, s, home / 'fiber_align' / 'catalog.db'


def _rows(db, sql):
    con = sqlite3.connect(str(db))
    con.row_factory = sqlite3.Row
    try:
        return [dict(r) for r in con.execute(sql)]
    finally:
        con.close()


def test_lockstep_rig_five_alignments_a_part_each(tmp_path):
    """Five align/release alignments, the part set before each: rows equal the summary's."""
    code, out, s, db = _bringup(tmp_path, '--rig', '--sync', 'lockstep', '--seed', '1',
                                '--cycles', '4', '--part', 'P')
    assert code == 0, out
    runs = _rows(db, 'SELECT * FROM runs')
    assert len(runs) == 1, runs
    r = runs[0]
    assert (r['machine'], r['sync_mode'], r['hardware']) == ('rig', 'lockstep', 0)
    assert r['ended_at'] > r['started_at'] and r['end_reason'].startswith('stopped')
    # the plants' last /diagnostics report (every 0.5 s; the plants may step on after the
    # observer's last sample, before the hold takes): not a figure to compare exactly
    assert r['watchdog_trips'] == 0 and r['cycles_kept'] > 0, (r, s)
    params = json.loads(r['parameters'])
    assert params['/rig/alignment_sequencer_2d']['machine'] == 'rig'
    rows = _rows(db, 'SELECT * FROM alignments ORDER BY seq')
    assert {a['run_id'] for a in rows} == {r['run_id']}
    assert_five_parts(rows, s)


def assert_five_parts(rows, s):
    """Check the 5 rows of a lockstep rig run (``--cycles 4 --part P``) against summary ``s``."""
    assert [(a['seq'], a['part_id'], a['final_state']) for a in rows] == [
        (k, 'P-%d' % k, 'TRACKING') for k in range(1, 6)]
    # lockstep: the catalogue's times are bringup's, counted in periods (1 ms)
    want = [s['time_to_peak_s']] + list(s['cycle_time_to_peak_s'])
    assert [a['time_to_peak_s'] for a in rows] == pytest.approx(want, abs=1e-9)
    for a in rows:
        assert 0.0 <= a['time_to_first_light_s'] < a['time_to_peak_s']
        # the launched 1 mW, the detector's noise above it
        assert a['samples'] > 0 and 0.0 < a['peak_power_w'] <= 1.01e-3
        # the simulated rig aligns to a few hundredths of a dB of the launched 1 mW; a
        # measured loss, so the detector's noise (the 1 % above) may put it 0.043 dB below 0
        assert -0.045 < a['final_loss_db'] < 0.5, a


def test_realtime_1d_run_align_and_switch_cycles(tmp_path):
    """The 1-D realtime run: the alignment and each switch cycle a row, as the summary's."""
    code, out, s, db = _bringup(tmp_path, '--scenario', 'align', '--cycles', '4')
    runs = _rows(db, 'SELECT * FROM runs')
    assert len(runs) == 1 and runs[0]['machine'] == '1d', (runs, out)
    assert runs[0]['sync_mode'] == 'realtime' and runs[0]['watchdog_trips'] == 0
    rows = _rows(db, 'SELECT * FROM alignments ORDER BY seq')
    assert len(rows) == 5, (rows, out)
    # each alignment the summary saw start is a row; one it saw reach TRACKING is TRACKING
    # (its observer reads alignment_state at depth 1 and may miss a status, never invents
    # one; the catalogue reads every status)
    states = s['align']['states']
    starts = [i for i, (_, st) in enumerate(states) if st in ('SEARCHING', 'PEAKING') and
              (i == 0 or states[i - 1][1] in ('IDLE', 'RELEASING'))]
    assert len(starts) == len(rows), (states, rows)
    for a, i, j in zip(rows, starts, starts[1:] + [len(states)]):
        if 'TRACKING' in [st for _, st in states[i:j]]:
            assert a['final_state'] == 'TRACKING', (a, states)
    # bringup fails a run whose last switch cycle did not end in TRACKING
    assert rows[0]['time_to_peak_s'] is not None and code == (
        0 if rows[-1]['final_state'] == 'TRACKING' else 1), out
    # the catalogue counts on the plant's stamps, the summary on the samples its observer
    # had when each state arrived (it lags on a loaded machine): within 50 ms
    assert rows[0]['time_to_peak_s'] == pytest.approx(s['align']['time_to_peak_s'], abs=0.05)


def _newer(path):
    con = sqlite3.connect(str(path))
    con.executescript('CREATE TABLE catalog_schema (version INTEGER, package_version TEXT);'
                      "INSERT INTO catalog_schema VALUES (99, '9.9');")
    con.commit()
    con.close()
    return str(path)


@pytest.mark.parametrize('case', ['missing folder', 'no files', 'refused', 'newer'])
def test_a_bad_catalogue_is_one_line_and_the_graph_runs_on(tmp_path, case):
    url = {'missing folder': lambda: str(tmp_path / 'no' / 'such' / 'catalog.db'),
           'no files': lambda: '/proc/fiber_align_catalog.db',
           'refused': lambda: 'postgresql://fa@127.0.0.1:1/line',
           'newer': lambda: _newer(tmp_path / 'newer.db')}[case]()
    # held 0.2 s: the lockstep run's comparison with the offline one is another test's
    code, out, s, _ = _bringup(tmp_path, '--rig', '--sync', 'lockstep', '--seed', '1',
                               '--duration', '0.2', '--catalog', url)
    assert code == 0 and s['state'] == 'TRACKING', out
    said = [line for line in out.splitlines() if 'rows wait in' in line and
            'run_catalog' in line and 'WARN' in line]
    assert len(said) == 1, out
    word = {'missing folder': 'no' + os.sep + 'such', 'no files': '/proc',
            'refused': '127.0.0.1', 'newer': 'version 99'}[case]
    assert word in said[0], said
    if case == 'newer':         # left as it was
        assert _rows(tmp_path / 'newer.db', 'SELECT version FROM catalog_schema') == [
            {'version': 99}]
