# SPDX-License-Identifier: Apache-2.0
"""
Offline align / switch / track through the control core's composite loop (1 kHz).

Reduced sizes keep the file fast; ``python -m bench bench_alignment`` runs the full
20 slots, 1,000 switch cycles and 60 s of tracking.
"""

import argparse
import json

import pytest

from fiber_align.alignment import sequencer as sq
from fiber_align.analysis import alignment_plots
from fiber_align.simulation import alignment_bench as ab, alignment_scenarios as sc


@pytest.fixture(scope='module')
def loop():
    return ab.make_loop('composite')


def test_align_composite_six_slots_across_the_range(loop):
    for i, slot in enumerate([1e-6, 13e-6, 26e-6, 39e-6, 52e-6, 64e-6]):
        r = sc.run('align', seed=20 + i, loop=loop, slot_m=slot)
        assert r['aligned'], r
        assert r['final_loss_db'] <= 0.05
        assert r['time_to_peak_s'] <= 0.5
        assert r['peak_samples'] <= 60
        assert r['control_rate_hz'] == pytest.approx(1000.0)


def test_switch_cycles_do_not_drift_composite(loop):
    r = sc.run('switch', seed=3, loop=loop, slot_m=45e-6, cycles=20)
    assert r['cycles'] == 20 and not r['switch_faults']
    assert abs(r['cycle_loss_drift_db']) <= 0.02
    assert r['cycle_loss_max_db'] <= 0.05


def test_switch_rise_time_composite(loop):
    rises = []
    for slot in (10e-6, 25e-6, 40e-6, 45e-6, 55e-6, 64e-6):
        r = sc.run('switch', seed=3, loop=loop, slot_m=slot, cycles=3)
        rises.append(r['switch_rise_time_s'])
    assert max(rises) <= 5e-3, rises


def test_tracking_under_drift_composite(loop):
    r = sc.run('track', seed=4, loop=loop, duration_s=3.0, drift_m_per_s=1e-6)
    assert r['tracking_state'] == sq.TRACKING
    assert r['tracking_max_loss_db'] <= 0.1


def test_broken_fiber_composite(loop):
    r = sc.run('align', seed=1, loop=loop, slot_m=30e-6, fiber_broken=True)
    assert r['state'] == sq.FAULT and 'no light found' in r['fault_reason']


@pytest.mark.ros  # starts a process
def test_run_cli_json_and_plot(tmp_path, capsys):
    png = tmp_path / 'align.png'
    ns = argparse.Namespace(scenario='switch', seed=2, json=True, plot=str(png),
                            cycles=2, loop='ideal', unrelated='ignored')
    assert sc.run_cli(ns, alignment_plots.plot_run) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ('time_to_first_light_s', 'time_to_peak_s', 'final_loss_db', 'peak_samples',
                'switch_rise_time_s', 'tracking_max_loss_db'):
        assert key in out
    assert out['final_loss_db'] <= 0.05 and out['switch_rise_time_s'] > 0
    assert png.stat().st_size > 10000


def test_run_cli_reports_a_fault_with_exit_code(capsys):
    ns = argparse.Namespace(scenario='align', seed=0, json=False, plot=None, slot=80e-6,
                            loop='ideal')
    assert sc.run_cli(ns) == 1
    assert 'FAULT' in capsys.readouterr().out
