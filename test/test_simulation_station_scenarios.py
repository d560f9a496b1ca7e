# SPDX-License-Identifier: Apache-2.0
"""The station scenarios offline: four composite loops, the cure, the CLI (reduced sizes)."""

import json

import numpy as np

from fiber_align import cli
from fiber_align.alignment.states import TRACKING
from fiber_align.simulation import station_scenarios as sc


def test_rig_is_four_independent_loops():
    rig = sc.StationRig('composite', 1e-3, 0)
    loops = rig.loops
    assert len({id(lp) for lp in loops}) == 4 and len({id(lp.plant) for lp in loops}) == 4
    rig.reset(8)
    for _ in range(40):
        rig.step((10e-6, 20e-6, 30e-6, 40e-6))
    assert np.allclose(rig.position, (10e-6, 20e-6, 30e-6, 40e-6), atol=0.1e-6)
    assert len(set(np.asarray(rig.measured) - np.asarray(rig.position))) == 4   # own noise


def test_cure_is_drawn_per_seed_in_the_stated_ranges():
    for seed in range(20):
        c = sc.random_cure(seed)
        for s in ('in', 'out'):
            assert 0.5e-6 <= c['cure_%s_amplitude_m' % s] <= 2e-6
            assert 10.0 <= c['cure_%s_duration_s' % s] <= 60.0
    assert sc.random_cure(1) == sc.random_cure(1) != sc.random_cure(2)


def test_tracking_holds_the_loss_through_a_cure_the_untracked_run_loses():
    # the drawn pulls, over 3 s instead of 10-60 s: faster than any drawn cure
    r = sc.run('cure', seed=4, cure_duration_s=3.0)
    assert r['state'] == TRACKING and r['end_state'] == TRACKING, r['end_fault_reason']
    assert r['max_loss_db'] <= 0.1
    assert r['untracked_final_loss_db'] > 0.3 > r['final_loss_db']
    assert r['untracked_max_loss_db'] >= r['untracked_final_loss_db'] - 0.05
    for k in ('cure_in_amplitude_m', 'cure_out_angle_rad', 'align_final_loss_db'):
        assert k in r


def test_cli_json_has_the_keys(capsys):
    rc = cli.main(['simulate', '--scenario', 'station', '--seed', '2', '--json'])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    for k in ('final_loss_db', 'time_to_peak_s', 'peak_samples', 'samples_ratio'):
        assert out[k] is not None
    for k in ('final_loss_db', 'time_to_peak_s', 'peak_samples'):
        assert out['baseline'][k] is not None
    assert out['baseline']['method'] == 'serial' and out['method'] == 'concurrent'


def test_cli_refuses_options_of_other_scenarios(capsys):
    assert cli.main(['simulate', '--scenario', 'cure', '--cycles', '3']) != 0
    assert 'do not apply' in capsys.readouterr().err
