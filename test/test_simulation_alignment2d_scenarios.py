# SPDX-License-Identifier: Apache-2.0
"""
Two-axis alignment through two composite loops at 1 kHz, noise on (reduced sizes).

``python -m bench bench_alignment2d`` runs the full 20 targets, 60 s of tracking and 1,000
switch cycles.
"""

import argparse
import json
import math

import numpy as np
import pytest

from fiber_align.analysis import alignment_plots
from fiber_align import cli
from fiber_align.simulation import alignment2d_scenarios as sc
from fiber_align.alignment import sequencer2d as s2d


@pytest.fixture(scope='module')
def rig():
    return sc.Rig2D('composite', 1e-3, 0)


def test_rig_is_two_independent_composite_loops(rig):
    lx, ly = rig.loops
    assert lx is not ly and lx.plant is not ly.plant and lx.fb is not ly.fb
    assert lx.name == ly.name == 'composite' and rig.period_s == 1e-3
    rig.reset(5)
    for _ in range(30):
        rig.step((20e-6, 40e-6))
    x, y = rig.position
    assert x == pytest.approx(20e-6, abs=0.1e-6) and y == pytest.approx(40e-6, abs=0.1e-6)
    mx, my = rig.measured
    assert mx != x and my != y                      # sensor noise on, own seed per axis


@pytest.mark.parametrize('target', [(3e-6, 62e-6), (33e-6, 31e-6), (61e-6, 4e-6)])
def test_align2d_reaches_the_peak(rig, target):
    r = sc.run('align2d', seed=3, rig=rig, target=target)
    assert r['state'] == s2d.TRACKING, r['fault_reason']
    assert r['aligned'], r
    assert r['final_loss_db'] <= 0.05          # dither included (0.014 dB of it)
    assert r['time_to_peak_s'] <= 1.0 and r['peak_samples'] <= 150
    assert r['control_rate_hz'] == pytest.approx(1000.0)
    b = r['baseline']
    assert b['method'] == 'hillclimb' and b['state'] == s2d.TRACKING
    assert b['target_x_m'] == r['target_x_m'] and b['target_y_m'] == r['target_y_m']
    assert r['samples_ratio'] == pytest.approx(b['peak_samples'] / r['peak_samples'])


def test_aligned_point_is_the_true_peak(rig):
    b = sc.build(7, target=(44.4e-6, 21.7e-6), rig=rig)
    sc.align_bench(b, loss_window_s=0.0)
    al = np.asarray(b.seq.aligned)
    # 0.05 dB is 0.56 um off the peak; the fit does an order of magnitude better
    assert math.hypot(al[0] - 44.4e-6, al[1] - 21.7e-6) < 0.15e-6
    st = b.seq.status()
    assert st['state'] == s2d.TRACKING and st['iterations'] >= 2
    assert st['aligned_x_m'] == pytest.approx(al[0])


def test_tracking_under_drift_and_vibration(rig):
    r = sc.run('track2d', seed=4, rig=rig, duration_s=3.0)
    assert r['tracking_state'] == s2d.TRACKING
    assert r['tracking_max_loss_db'] <= 0.1
    assert r['tracking_time_s'] > 1.5
    assert r['baseline']['tracking_max_loss_db'] is not None      # measured beside it


def test_switch_cycles_repeak_without_drift(rig):
    r = sc.run('switch2d', seed=6, rig=rig, cycles=20)
    assert r['cycles'] == 20 and not r['switch_faults'] and r['cycles_not_tracking'] == 0
    assert r['cycle_loss_max_db'] <= 0.05
    assert abs(r['cycle_loss_drift_db']) <= 0.01
    assert r['baseline']['cycles'] == 20


@pytest.mark.parametrize('target,axis', [((75e-6, 30e-6), 'x'), ((30e-6, -8e-6), 'y')])
def test_target_out_of_reach_names_the_axis(rig, target, axis):
    for method in sc.METHODS:
        b = sc.build(1, method=method, target=target, rig=rig)
        r = sc.align_bench(b)
        assert r['state'] == s2d.FAULT
        assert r['fault_reason'].startswith('target out of reach in %s' % axis), r


def test_broken_fiber_and_power_lost_while_tracking(rig):
    b = sc.build(1, target=(30e-6, 30e-6), rig=rig, fiber_broken=True)
    r = sc.align_bench(b)
    assert r['state'] == s2d.FAULT and r['fault_reason'].startswith('no light found anywhere')
    assert b.t - 0.02 < b.seq.p['search_timeout_s']
    b = sc.build(2, target=(30e-6, 40e-6), rig=rig)
    assert sc.align_bench(b)['state'] == s2d.TRACKING
    t0 = b.t
    b.link.coupling.fiber_broken = True
    b.run_until(t0 + 0.2, lambda x: x.seq.state == s2d.FAULT)
    assert b.seq.state == s2d.FAULT and 'power lost while tracking' in b.seq.fault_reason
    assert b.t - t0 < 0.05
    ok, _ = b.seq.switch(True)
    assert not ok
    assert b.seq.release()[0]


def test_pure_core_faults_and_api():
    seq = s2d.Sequencer2D(period_s=sc.graph_period_s())
    sp = seq.update(0.0, 0.0, 0.0, 1e-10)
    assert isinstance(sp, tuple) and len(sp) == 2 and sp == (0.0, 0.0)
    assert seq.switch(True)[0] is False                 # nothing aligned yet
    assert seq.align()[0] and seq.state == s2d.SEARCHING
    for k in range(1, int(seq.p['floor_samples']) + 5):  # a reading that never changes
        seq.update(k * 1e-3, 0.0, 0.0, 1e-10)
    # in the dark: the meter's floor, not a dead sensor (docs/alignment.md)
    assert seq.state == s2d.SEARCHING
    assert seq.floor == pytest.approx((1e-10, seq.p['dark_floor_w']))
    seq.release()
    seq.align()
    seq.update(0.1, 0.0, 0.0, None)
    for k in range(1, 15):                              # no power readings
        seq.update(0.1 + k * 1e-3, 0.0, 0.0, None)
    assert seq.state == s2d.FAULT and 'sensor silent' in seq.fault_reason
    seq.release()
    seq.align()
    seq.update(0.2, 0.0, 0.0, 1e-10, driver_active=False)
    assert seq.state == s2d.HELD                        # waits for the re-arm ...
    down_s = seq.p['driver_down_timeout_s']
    seq.update(0.2 + 0.5 * down_s, 0.0, 0.0, 1e-10, driver_active=False)
    assert seq.state == s2d.HELD
    seq.update(0.2 + 1.01 * down_s, 0.0, 0.0, 1e-10, driver_active=False)
    assert seq.state == s2d.FAULT and 'driver inactive' in seq.fault_reason   # ... so long


def test_cli_json_has_the_keys(capsys):
    rc = cli.main(['simulate', '--scenario', 'align2d', '--seed', '2', '--json'])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    for key in ('final_loss_db', 'time_to_peak_s', 'peak_samples'):
        assert isinstance(out[key], (int, float))
        assert isinstance(out['baseline'][key], (int, float))
    assert out['final_loss_db'] <= 0.05 and out['scenario'] == 'align2d'
    assert out['baseline']['method'] == 'hillclimb'


@pytest.mark.ros  # starts a process
def test_run_cli_plot(tmp_path, capsys):
    png = tmp_path / 'switch2d.png'
    ns = argparse.Namespace(scenario='switch2d', seed=1, json=False, plot=str(png), cycles=2,
                            loop='composite', unrelated='ignored')
    assert sc.run_cli(ns, alignment_plots.plot_run2d) == 0
    assert 'hillclimb' in capsys.readouterr().out        # the baseline's row, by its method
    assert png.stat().st_size > 20000


def test_core_replays_sample_for_sample(rig):
    """A node feeding the same readings gets the same setpoints (what lockstep relies on)."""
    b = sc.build(9, target=(12e-6, 50e-6), rig=rig, record=True)
    sc.align_bench(b)
    for _ in range(2):
        b.seq.switch(False)
        b.run_until(b.t + 0.03)
        b.seq.switch(True)
        b.run_until(b.t + 0.06)
    tr = b.trace()
    # replay up to the first switch-off, a command the replay does not send
    n = list(tr['state']).index(s2d.RELEASING)
    seq = s2d.Sequencer2D(period_s=sc.graph_period_s())
    out = []
    for k in range(n):
        if k == 20:                                     # align_bench commands at 20 ms
            seq.align()
        out.append(seq.update(tr['t'][k], tr['mx'][k], tr['my'][k], tr['p'][k]))
    got = np.asarray(out)
    assert n > 100 and seq.state == s2d.TRACKING
    assert np.array_equal(got[:, 0], tr['rx'][:n]) and np.array_equal(got[:, 1], tr['ry'][:n])
