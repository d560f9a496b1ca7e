# SPDX-License-Identifier: Apache-2.0
"""The station's pure core: search coverage, the joint fit, commands, HELD."""

import math

import numpy as np
import pytest

from fiber_align.alignment import search2d as s2
from fiber_align.alignment import station as st
from fiber_align.alignment import station_search as ss
from fiber_align.alignment import station_serial as ser
from fiber_align.alignment.states import FAULT, HELD, IDLE, PEAKING, SEARCHING, TRACKING
from fiber_align.alignment.station_peak import SIDES
from fiber_align.simulation import station_scenarios as sc
from fiber_align.simulation.seeds2d import graph_period_s


@pytest.fixture(scope='module')
def rig():
    return sc.StationRig('composite', 1e-3, 0)


def test_search_path_passes_every_joint_peak_within_the_capture():
    seq = st.Station(period_s=graph_period_s())
    p = seq.p
    w, half = p['coupling_radius_m'], p['search_half_width_m']
    path = seq.search_path(seq.park)
    ds = 0.1e-6
    pts = np.array([path.advance(ds) for _ in range(int(path.length_m / ds) + 2)])
    assert path.done
    # light reaches the detector when (d_in^2 + d_out^2) / w^2 <= D ln(10) / 10
    limit = p['search_capture_db'] * math.log(10) / 10 * w * w
    chord = (p['confirm_samples'] + 1) * p['search_speed_m_per_s'] * seq.period_s
    rng = np.random.default_rng(7)
    for _ in range(200):
        target = seq.park + rng.uniform(-half + 1e-6, half - 1e-6, 4)
        d2 = np.sum((pts - target) ** 2, axis=1)
        inside = d2 <= limit
        assert inside.any()
        # it stays inside for the confirm chord: a run of consecutive path samples
        runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], inside, [0]]))))[::2]
        assert runs.max() * ds >= chord


def test_search_design_follows_the_capture_budget():
    n, m = ss.search_design(2.12e-6, 48.0, 0.5, 6e-6, 21e-6)
    d_slow = ss.s2.capture_radius(2.12e-6, 24.0)
    assert 21e-6 / n * math.sqrt(2) <= d_slow           # every input point within reach
    n2, m2 = ss.search_design(2.12e-6, 40.0, 0.5, 6e-6, 21e-6)
    assert n2 >= n and m2 >= m                           # less light: a finer search
    with pytest.raises(ValueError):
        ss.search_design(2.12e-6, 48.0, 1.0, 6e-6, 21e-6)


def test_joint_fit_recovers_the_separable_paraboloid():
    rng = np.random.default_rng(1)
    vertex = np.array([20e-6, 30e-6, 40e-6, 10e-6])
    k_in, k_out = 0.2e12, 0.3e12
    pos = vertex + rng.uniform(-2e-6, 2e-6, (9, 4))
    lp = -3.0 - k_in * np.sum((pos[:, :2] - vertex[:2]) ** 2, 1) - \
        k_out * np.sum((pos[:, 2:] - vertex[2:]) ** 2, 1)
    v, (ki, ko), lp0 = s2.fit_log_paraboloid_groups(pos, np.exp(lp), SIDES)
    assert np.allclose(v, vertex, atol=1e-12) and (ki, ko, lp0) == pytest.approx(
        (k_in, k_out, -3.0))
    # with a curvature prior 5 readings suffice; the right prior is exact
    lp = -3.0 - k_in * np.sum((pos - vertex) ** 2, 1)
    v, (ki, ko), _ = s2.fit_log_paraboloid_groups(pos[:5], np.exp(lp[:5]), SIDES,
                                                  curvature=k_in)
    assert np.allclose(v, vertex, atol=1e-12) and ki == ko == pytest.approx(k_in)
    assert s2.fit_log_paraboloid_groups(pos[:6], np.exp(lp[:6]), SIDES) is None


@pytest.mark.parametrize('seed', [2, 5])
def test_concurrent_reaches_the_joint_peak_in_fewer_samples_than_serial(rig, seed):
    r = sc.run('station', seed=seed, rig=rig)
    b = r['baseline']
    assert r['state'] == b['state'] == TRACKING, (r['fault_reason'], b['fault_reason'])
    assert r['final_loss_db'] <= 0.05 and b['final_loss_db'] <= 0.05   # dithers included
    assert r['aligned_offset_m'] < 0.1e-6 and b['aligned_offset_m'] < 0.1e-6
    assert r['facets_m'] == b['facets_m']
    assert r['time_to_first_light_s'] == b['time_to_first_light_s']      # one search
    assert r['samples_ratio'] == pytest.approx(r['peak_samples'] / b['peak_samples'])
    assert r['samples_ratio'] <= 0.6
    off = np.abs(np.asarray(r['facets_m']) - st.Station(period_s=graph_period_s()).park)
    assert np.all(off >= 2e-6) and np.all(off <= 20e-6)


def test_serial_peaks_one_side_then_the_other_until_no_gain(rig):
    b = sc.build(3, 'serial', rig=rig)
    sc.align_bench(b, loss_window_s=0.0)
    sides = [text.split(' side peaked')[0] for _, _, text in b.seq.events
             if ' side peaked' in text]
    assert sides[:3] == ['input', 'output', 'input'] and len(sides) <= 8
    assert b.seq.state == TRACKING
    assert isinstance(b.seq._sides[0], ser.SidePeaker)


def test_no_light_is_a_fault_that_says_why(rig):
    b = sc.build(1, 'concurrent', rig=rig, fiber_broken=True)
    r = sc.align_bench(b)
    assert r['state'] == FAULT and 'no light found' in r['fault_reason']
    assert 'broken fiber' in r['fault_reason']
    assert b.seq.release()[0]
    b.run_until(b.t + 0.05)
    assert b.seq.state == IDLE


def test_release_and_switch_on_re_peak_both_sides(rig):
    b = sc.build(2, 'concurrent', rig=rig)
    sc.align_bench(b)
    aligned = np.asarray(b.seq.aligned).copy()
    assert b.seq.switch(False)[0]
    b.run_until(b.t + 0.05)
    assert b.seq.state == IDLE and np.allclose(b.rig.position, b.seq.park, atol=0.2e-6)
    ok, msg = b.seq.switch(True)
    assert ok and b.seq.state == PEAKING, msg
    b.run_until(b.t + 0.2, lambda x: x.seq.state == TRACKING)
    assert b.seq.state == TRACKING and b.seq.peak_samples < 60
    assert np.linalg.norm(np.asarray(b.seq.aligned) - aligned) < 0.2e-6
    assert b.true_loss() < 0.05


def test_parameters_are_checked():
    with pytest.raises(ValueError, match='unknown'):
        st.Station(period_s=1e-3, bogus=1.0)
    with pytest.raises(ValueError, match='distinct'):
        st.Station(period_s=1e-3, dither_out_frequency_hz=100.0)


@pytest.mark.parametrize('when', ['tracking', 'peaking'])
def test_a_driver_down_holds_every_axis_and_the_station_resumes_after_the_re_arm(rig, when):
    b = sc.build(2, 'concurrent', rig=rig)
    if when == 'tracking':
        sc.align_bench(b)
    else:
        b.run_until(0.02)
        b.seq.align()
        b.run_until(2.0, lambda x: x.seq.state == PEAKING and x.seq.peak_samples > 12)
    b.driver_active = (True, True, False, True)
    b.step()
    assert b.seq.state == HELD and 'driver of x_out down' in b.seq.hold_reason
    held = np.asarray(b.seq.setpoint)
    for _ in range(100):
        b.step()
        assert np.allclose(b.seq.setpoint, held)           # no axis moves, no dither
    b.driver_active = None
    b.run_until(b.t + 0.5, lambda x: x.seq.state == TRACKING)
    assert b.seq.state == TRACKING, b.seq.events[-3:]
    assert any('drivers back' in text for _, _, text in b.seq.events)
    b.run_until(b.t + 0.02)
    assert b.true_loss() < 0.05


def test_a_driver_down_too_long_is_a_fault(rig):
    b = sc.build(2, 'concurrent', rig=rig, seq_overrides=dict(driver_down_timeout_s=0.05))
    sc.align_bench(b)
    b.driver_active = False
    b.run_until(b.t + 0.1)
    assert b.seq.state == FAULT and 'driver inactive' in b.seq.fault_reason


def test_what_the_drivers_publish_holds_the_station_and_refuses_align(rig):
    """The node's path: a driver's ``drive_held`` (not ``update``'s argument) holds."""
    b = sc.build(2, 'concurrent', rig=rig)
    for name in st.DRIVERS:
        b.seq.driver_lifecycle('active', name)
        b.seq.driver_held(False, name)
    sc.align_bench(b)
    assert b.seq.state == TRACKING
    assert b.seq.driver_held(True, 'out/y/actuator_driver')        # acted at once
    assert b.seq.state == HELD and 'y_out' in b.seq.hold_reason
    assert 'out/y/actuator_driver' in b.seq.hold_reason
    held = np.asarray(b.seq.setpoint)
    for _ in range(50):
        b.step()
        assert np.allclose(b.seq.setpoint, held) and b.seq.state == HELD
    b.seq.release()
    ok, why = b.seq.align()
    assert not ok and 'out/y/actuator_driver' in why
    b.seq.driver_held(False, 'out/y/actuator_driver')
    assert b.seq.align()[0]
    b.run_until(b.t + 5.0, lambda x: x.seq.state in (TRACKING, FAULT))
    assert b.seq.state == TRACKING, b.seq.fault_reason


def test_a_lit_start_then_a_dark_pattern_walks_a_search_path():
    """Light at the start skips the walk: a false first light must build one, not crash."""
    seq = st.Station(period_s=graph_period_s())
    seq.sp = np.asarray(seq.park, dtype=float).copy()
    seq._path = None                    # lit at the start (the floor found it bright)
    seq._false_light()
    assert seq.state == SEARCHING and seq._phase == seq.SEARCH_PHASE
    assert seq._path is not None and not seq._path.done
    ahead = np.asarray(seq._path.advance(20e-6), dtype=float)     # 20 um along the walk
    assert np.max(np.abs(ahead - seq.sp)) > 1e-6
