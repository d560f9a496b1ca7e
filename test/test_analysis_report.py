# SPDX-License-Identifier: Apache-2.0
"""``fiber-align analyze`` reports by what the bag holds: an alignment run or a tracking run."""

import json

import numpy as np

from fiber_align.analysis import bag as bagio, report as rp
from fiber_align.analysis.cli import analyze_bag

RATE_HZ = 1000.0
N = 300
WALL0 = 1_700_000_000_000_000_000
SLOT_M = 40e-6
P0_W = 1e-3
W_M = 5.2e-6


def _power(y):
    return P0_W * np.exp(-((y - SLOT_M) / W_M) ** 2)


def _status(state, k, peak_samples=0, fault=''):
    return json.dumps({'state': state, 'phase': '', 'fault_reason': fault,
                       'threshold_w': 1e-9, 'peak_samples': peak_samples,
                       'sample_time_s': None if k is None else k / RATE_HZ})


def _alignment_series():
    """
    Return a lockstep alignment run: idle, a search in 1 um jumps, peaking, tracking, a switch.

    Samples (index k, time k / RATE_HZ): align at 20, TRACKING at 100, switch off at 150
    (RELEASING, IDLE at 152), on at 200 (PEAKING), TRACKING again at 220.
    """
    k = np.arange(N)
    stamp = np.round(k / RATE_HZ * 1e9).astype(np.int64)
    wall = WALL0 + k * 3_000_000
    r = np.zeros(N)
    r[20:60] = 1e-6 * (k[20:60] - 19)            # the search: a 1 um jump every sample
    r[60:100] = np.linspace(30e-6, SLOT_M, 40)  # peaking
    r[100:150] = SLOT_M
    r[150:200] = 0.0
    r[200:] = SLOT_M
    y = np.concatenate([[0.0], r[:-1]])          # the loop follows one sample late
    states = [('IDLE', None, 0, 0), ('SEARCHING', 19, 0, 0), ('PEAKING', 59, 0, 0),
              ('TRACKING', 99, 35, 0), ('RELEASING', 149, 35, 0), ('IDLE', 151, 35, 0),
              ('PEAKING', 199, 0, 0), ('TRACKING', 219, 20, 0)]
    st_wall = [WALL0 if ks is None else wall[ks] + 500 for _, ks, _, _ in states]
    return {
        'clock': {'t_ns': wall, 'clock_ns': stamp},
        'displacement': {'t_ns': wall + 10, 'stamp_ns': stamp, 'position': y},
        'reference': {'t_ns': wall + 20, 'data': r},
        'drive_voltage': {'t_ns': wall + 40, 'data': r * 1e6},
        'optical_power': {'t_ns': wall + 10, 'data': _power(y)},
        'alignment_state': {'t_ns': np.array(st_wall, np.int64),
                            'data': [_status(s, ks, pk) for s, ks, pk, _ in states]},
    }


def _tracking_series():
    """Return a lockstep step run: 0 -> 20 um at 50 ms, with no sequencer."""
    k = np.arange(N)
    stamp = np.round(k / RATE_HZ * 1e9).astype(np.int64)
    wall = WALL0 + k * 3_000_000
    r = np.where(k >= 50, 20e-6, 0.0)
    y = 20e-6 * np.clip(k - 50, 0, None) / (np.clip(k - 50, 0, None) + 3.0)
    return {
        'clock': {'t_ns': wall, 'clock_ns': stamp},
        'displacement': {'t_ns': wall + 10, 'stamp_ns': stamp, 'position': y},
        'reference': {'t_ns': wall + 20, 'data': r},
        'drive_voltage': {'t_ns': wall + 40, 'data': r * 1e6},
    }


def _table(md):
    """Return the (section, metric, value) rows of a Markdown report."""
    rows = []
    for line in md.splitlines():
        if line.startswith('| ') and not line.startswith('| section'):
            rows.append(tuple(c.strip() for c in line.strip('|').split('|')))
    return rows


def test_alignment_report_has_alignment_table_first_and_no_step_rows(tmp_path):
    """An alignment bag: alignment table first, no step or tracking rows, figures right."""
    bagio.write_bag(tmp_path / 'align', _alignment_series())
    res, _ = analyze_bag(tmp_path / 'align', None, (-20.0, 100.0))
    assert res['kind'] == 'alignment'
    assert 'steps' not in res['metrics']['loop'] and 'tracking' not in res['metrics']['loop']
    al = res['metrics']['align']
    assert al['state'] == 'TRACKING'
    assert [k for k, _ in al['states']] == [0, 20, 60, 100, 150, 152, 200, 220]
    assert abs(al['time_to_peak_s'] - 80 / RATE_HZ) < 1e-9
    assert al['peak_samples'] == 35
    # light (>= 1 nW) once the tip is within about 4.6 mode radii of the slot
    lit = int(np.argmax(_power(_alignment_series()['displacement']['position']) >= 1e-9))
    assert abs(al['time_to_first_light_s'] - (lit - 20) / RATE_HZ) < 1e-12
    assert al['switch_cycles'] == 1 and len(al['cycles']) == 1
    assert 0.0 <= al['final_loss_db'] < 0.01 and al['tracking_max_loss_db'] >= 0.0
    rp.write_report(tmp_path / 'r.md', res, [])
    rows = _table((tmp_path / 'r.md').read_text())
    assert rows[0][0] == 'alignment'
    head = [name for sec, name, _ in rows[:10]]
    assert head[:6] == ['final state', 'time to first light', 'time to peak', 'peak samples',
                        'final loss', 'switch cycles']
    assert 'tracking loss (max)' in head
    assert not any(sec.startswith('step') or sec == 'tracking' for sec, _, _ in rows)
    text = rp.to_text(res)
    assert 'alignment run' in text.splitlines()[0] and 'step ' not in text
    html_path = rp.write_report(tmp_path / 'r.html', res, [])
    assert 'settling time' not in html_path.read_text()


def test_tracking_report_keeps_step_and_tracking_tables(tmp_path):
    """A step bag without a sequencer: the tracking and step rows, no alignment table."""
    bagio.write_bag(tmp_path / 'step', _tracking_series())
    res, _ = analyze_bag(tmp_path / 'step', None, (-20.0, 100.0))
    assert res['kind'] == 'tracking' and 'align' not in res['metrics']
    assert len(res['metrics']['loop']['steps']) == 1
    rp.write_report(tmp_path / 'r.md', res, [])
    rows = _table((tmp_path / 'r.md').read_text())
    assert rows[0][:2] == ('tracking', 'RMS error')
    assert any(sec.startswith('step 1') and name.startswith('settling time (band +-')
               for sec, name, _ in rows)
    assert not any(sec == 'alignment' for sec, _, _ in rows)


def test_sequencer_left_idle_is_a_tracking_run(tmp_path):
    """A state topic that never leaves IDLE (or names no sequencer state) is no alignment."""
    series = _tracking_series()
    series['alignment_state'] = {'t_ns': np.array([WALL0], np.int64),
                                 'data': [_status('IDLE', None)]}
    bagio.write_bag(tmp_path / 'idle', series)
    res, _ = analyze_bag(tmp_path / 'idle', None, (-20.0, 100.0))
    assert res['kind'] == 'tracking' and res['metrics']['loop']['steps']


def test_alignment_without_power_is_named(tmp_path):
    """An alignment bag without optical power says what the alignment figures lack."""
    series = _alignment_series()
    del series['optical_power']
    bagio.write_bag(tmp_path / 'dark', series)
    res, _ = analyze_bag(tmp_path / 'dark', None, (-20.0, 100.0))
    assert res['kind'] == 'alignment' and 'align' not in res['metrics']
    assert any('no optical_power topic' in n for n in res['notes'])
    rows = rp.metrics_rows(res)
    assert rows[0][0] == 'alignment' and not any(s.startswith('step') for s, _, _ in rows)
