# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align simulate --catalog`` and ``fiber-align runs``: the records and their reading.

In process (``fiber_align.cli.main``), on SQLite; the same over PostgreSQL is in
``test_records_postgres.py``.
"""

import csv
import json
import math
import sqlite3

import numpy as np
import pytest

from fiber_align import cli
from fiber_align.graph.machines import MACHINES
from fiber_align.records import report
from fiber_align.tools import runs_cli


def run_cli(capsys, *argv):
    """Run ``fiber-align argv``; return ``(code, stdout, stderr)``."""
    code = cli.main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture
def home(tmp_path, monkeypatch):
    """Point ``ROS_HOME`` at a temporary folder; return the default catalogue's path."""
    monkeypatch.setenv('ROS_HOME', str(tmp_path / 'ros'))
    return tmp_path / 'ros' / 'fiber_align' / 'catalog.db'


def test_simulate_records_what_it_reports(capsys, home):
    """The rows ``sqlite3`` reads equal the figures ``simulate --json`` prints."""
    code, out, err = run_cli(capsys, 'simulate', '--scenario', 'switch', '--json',
                             '--catalog', 'default', '--part', 'P-17')
    assert code == 0, err
    res = json.loads(out)
    conn = sqlite3.connect(str(home))
    run = conn.execute('SELECT run_id, machine, sync_mode, hardware, cycles_kept, end_reason '
                       'FROM runs').fetchall()
    assert len(run) == 1
    run_id, machine, sync, hw, kept, end = run[0]
    assert (machine, sync, hw, end) == ('1d', 'offline', 0, res['end_state'])
    assert kept == round(res['simulated_s'] * res['control_rate_hz'])
    assert run_id in err
    got = conn.execute('SELECT seq, part_id, final_state, final_loss_db, time_to_peak_s, '
                       'time_to_first_light_s, samples FROM alignments WHERE run_id = ? '
                       'ORDER BY seq', (run_id,)).fetchall()
    conn.close()
    assert len(got) == 1 + res['cycles'] == 6
    assert got[0] == (1, 'P-17', res['state'], res['final_loss_db'], res['time_to_peak_s'],
                      res['time_to_first_light_s'], res['samples'])
    assert [g[3] for g in got[1:]] == res['cycle_loss_db']
    assert {g[1] for g in got} == {'P-17'}


def test_machine_names_are_the_graphs():
    """The catalogue's machine of each scenario family is a machine of the graph."""
    assert set(runs_cli.MACHINE_OF_FAMILY.values()) <= set(MACHINES)


def test_catalog_needs_an_alignment_scenario(capsys, home):
    """--catalog on a scenario without alignments, --part without --catalog: usage errors."""
    code, _, err = run_cli(capsys, 'simulate', '--scenario', 'step', '--catalog', 'default')
    assert code == 2 and 'records alignments' in err
    code, _, err = run_cli(capsys, 'simulate', '--scenario', 'align', '--part', 'P')
    assert code == 2 and '--part needs --catalog' in err


def test_a_catalogue_in_a_missing_folder_warns_and_the_run_goes_on(capsys, home, tmp_path):
    """One warning line; the run's own exit code and output stand."""
    url = str(tmp_path / 'missing' / 'c.db')
    code, out, err = run_cli(capsys, 'simulate', '--scenario', 'align', '--json',
                             '--catalog', url, '--part', 'P')
    assert code == 0 and json.loads(out)['state'] == 'TRACKING'
    lines = [x for x in err.splitlines() if 'warning' in x]
    assert len(lines) == 1 and 'does not exist' in lines[0] and 'spool' in lines[0]


def test_list_show_export_report(capsys, home, tmp_path):
    """Two runs, two machines, two parts: the filters, show, the CSV and the report agree."""
    for scen, part in (('switch', 'A'), ('align2d', 'B')):
        assert run_cli(capsys, 'simulate', '--scenario', scen, '--json', '--catalog',
                       'default', '--part', part)[0] == 0
    code, out, _ = run_cli(capsys, 'runs', 'list', '--json')
    runs = json.loads(out)
    assert code == 0 and [r['machine'] for r in runs] == ['1d', 'rig']
    assert [r['alignments'] for r in runs] == [6, 1]
    code, out, _ = run_cli(capsys, 'runs', 'list', '--json', '--part', 'B')
    assert [r['machine'] for r in json.loads(out)] == ['rig']
    code, out, _ = run_cli(capsys, 'runs', 'list', '--json', '--alignments', '--machine', '1d')
    assert [a['seq'] for a in json.loads(out)] == [1, 2, 3, 4, 5, 6]
    code, out, _ = run_cli(capsys, 'runs', 'list', '--json', '--until', '2000-01-01')
    assert json.loads(out) == []
    code, out, _ = run_cli(capsys, 'runs', 'list', '--json', '--state', 'FAULT')
    assert json.loads(out) == []
    code, out, _ = run_cli(capsys, 'runs', 'show', runs[1]['run_id'][:8], '--json')
    shown = json.loads(out)
    assert code == 0 and shown['run']['run_id'] == runs[1]['run_id']
    assert shown['alignments'][0]['part_id'] == 'B'
    assert shown['alignments'][0]['figures']['target_x_m'] > 0
    code, _, err = run_cli(capsys, 'runs', 'show', 'nosuchrun')
    assert code == 2 and 'no run nosuchrun' in err and err.count('\n') == 1
    path = tmp_path / 'a.csv'
    assert run_cli(capsys, 'runs', 'export', '--csv', str(path))[0] == 0
    with open(path, newline='') as f:
        table = list(csv.DictReader(f))
    assert len(table) == 7 and table[0]['part_id'] == 'A' and table[-1]['machine'] == 'rig'
    out_dir = tmp_path / 'rep'
    code, out, _ = run_cli(capsys, 'runs', 'report', '--usl-loss-db', '0.011', '--out',
                           str(out_dir))
    assert code == 0
    page = (out_dir / 'report.md').read_text()
    for png in ('histograms.png', 'imr_1d.png'):
        assert (out_dir / png).stat().st_size > 10000 and png in page
    losses = [float(r['final_loss_db']) for r in table]
    passed = sum(1 for r in table if r['final_state'] == 'TRACKING' and
                 float(r['final_loss_db']) <= 0.011)
    assert '| all | 7 | 7 | %d | %.2f |' % (passed, 100.0 * passed / 7) in page
    assert 0 < passed < 7 and max(losses) > 0.011


def test_a_catalogue_that_is_not_there_is_one_line(capsys, home, tmp_path):
    """The reading tools do not create a catalogue: a missing file is one line, exit 2."""
    code, _, err = run_cli(capsys, 'runs', 'list', '--catalog', str(tmp_path / 'x.db'))
    assert code == 2 and 'does not exist' in err and err.count('\n') == 1
    assert not (tmp_path / 'x.db').exists()


def test_capability_and_chart_limits_by_hand():
    """Cpk from the mean moving range, Ppk from the standard deviation, I-MR limits."""
    x = np.array([0.10, 0.14, 0.12, 0.16, 0.11, 0.13])
    state = np.array(['TRACKING'] * 5 + ['FAULT'], dtype=object)
    ttp = np.array([0.1, 0.2, np.nan, 0.3, 0.4, 0.5])
    s = report.stats(x, state, ttp, usl_db=0.15)
    mrbar = np.mean([0.04, 0.02, 0.04, 0.05, 0.02])
    mean = x.mean()
    assert s['passed'] == 4 and math.isclose(s['yield'], 4 / 6)
    assert math.isclose(s['cpk'], (0.15 - mean) / (3 * mrbar / 1.128), rel_tol=1e-12)
    assert math.isclose(s['ppk'], (0.15 - mean) / (3 * np.std(x, ddof=1)), rel_tol=1e-12)
    assert math.isclose(s['median_time_to_peak_s'], 0.3)
    lim = report.limits(x)
    assert math.isclose(lim['i_ucl'], mean + 2.66 * mrbar, rel_tol=1e-3)
    assert math.isclose(lim['mr_ucl'], 3.267 * mrbar, rel_tol=1e-12)
    outlier = np.append(x, 0.5)
    assert report.stats(outlier, np.append(state, 'TRACKING'), np.append(ttp, 0.1),
                        0.15)['i_out'] == 1
