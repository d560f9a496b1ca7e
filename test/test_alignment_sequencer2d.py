# SPDX-License-Identifier: Apache-2.0
"""Properties of the 2-D estimators and sequencer: spiral coverage, paraboloid fit, HELD."""

import math

import numpy as np
import pytest

from fiber_align.alignment import search2d as s2
from fiber_align.alignment import sequencer2d as s2d
from fiber_align.simulation.seeds2d import graph_period_s

W = 5.2e-6
K = 1.0 / W ** 2                  # curvature of ln P (1/m^2), no gap
XY = ((0, 1),)                    # one circular paraboloid of x and y


def _min_dist(grid, path, chunk=400):
    """Return, for each grid point, the distance (m) to the nearest path point."""
    out = []
    for i in range(0, len(grid), chunk):
        d = np.hypot(grid[i:i + chunk, None, 0] - path[None, :, 0],
                     grid[i:i + chunk, None, 1] - path[None, :, 1])
        out.append(d.min(axis=1))
    return np.concatenate(out)


def test_spiral_pitch_leaves_no_gap_larger_than_the_capture_radius():
    seq = s2d.Sequencer2D(period_s=graph_period_s())
    p = seq.p
    rc = seq.capture_radius_m
    assert rc == pytest.approx(W * math.sqrt(p['spiral_capture_db'] * math.log(10) / 10))
    assert seq.period_s == pytest.approx(1e-3)     # 1 / rate_hz of config/plant.yaml
    chord = (p['confirm_samples'] + 1) * p['search_speed_m_per_s'] * seq.period_s
    assert seq.pitch_m == pytest.approx(2 * math.sqrt(rc ** 2 - (chord / 2) ** 2))
    path = seq.search_path(seq.park).points(0.25e-6)
    path = np.clip(path, seq.lo, seq.hi)           # the setpoints are clipped to the square
    g = np.linspace(0.0, 65e-6, 60)
    grid = np.array([(a, b) for a in g for b in g])
    dmin = _min_dist(grid, path)
    # every point of the square is within half a pitch of the walk, and that is inside the
    # capture radius with room for the confirm chord
    assert dmin.max() <= 0.5 * seq.pitch_m + 0.3e-6
    assert 0.5 * seq.pitch_m < rc
    # the walk stays within the capture radius of each point for at least the chord
    near = []
    for q in grid[::7]:
        near.append(np.sum(np.hypot(*(path - q).T) < rc) * 0.25e-6)
    assert min(near) >= chord
    # and the walk is short: at most the transit plus pi R^2 / pitch of the whole spiral
    steps = np.hypot(*np.diff(path, axis=0).T).sum()
    sp = seq.search_path(seq.park)
    assert steps <= sp.transit + math.pi * sp.r_max ** 2 / seq.pitch_m


def _fit_cov_std(x, y, x0, y0, sigma):
    """Return the predicted standard deviation (m) of the fitted vertex x and y."""
    xm, ym = x.mean(), y.mean()
    xs, ys = (x - xm) * 1e6, (y - ym) * 1e6
    a = np.vstack([np.ones_like(xs), xs, ys, -(xs ** 2 + ys ** 2)]).T
    cov = sigma ** 2 * np.linalg.inv(a.T @ a)
    k = K * 1e-12
    bx, by = 2 * k * (x0 - xm) * 1e6, 2 * k * (y0 - ym) * 1e6
    # vertex = b / (2 k): gradients w.r.t. (a, bx, by, k)
    jx = np.array([0.0, 1 / (2 * k), 0.0, -bx / (2 * k * k)])
    jy = np.array([0.0, 0.0, 1 / (2 * k), -by / (2 * k * k)])
    return math.sqrt(jx @ cov @ jx) * 1e-6, math.sqrt(jy @ cov @ jy) * 1e-6


def test_paraboloid_fit_recovers_a_noisy_gaussian_peak_within_the_noise():
    rng = np.random.default_rng(7)
    x0, y0 = 31.3e-6, 18.9e-6
    c = np.array([31.0e-6, 19.6e-6])            # cross centre 0.76 um from the peak
    h = 1.5e-6
    pts = np.array([c, c + (h, 0), c + (0, h), c - (h, 0), c - (0, h)])
    sigma = 0.02 * math.log(10) / 10 / math.sqrt(2)   # two readings of 0.02 dB RIN
    sx, sy = _fit_cov_std(pts[:, 0], pts[:, 1], x0, y0, sigma)
    assert 0.005e-6 < sx < 0.05e-6 and 0.005e-6 < sy < 0.05e-6
    errs = []
    for _ in range(400):
        lp = math.log(1e-3) - K * ((pts[:, 0] - x0) ** 2 + (pts[:, 1] - y0) ** 2)
        p = np.exp(lp + sigma * rng.standard_normal(len(pts)))
        (x, y), (k,), _ = s2.fit_log_paraboloid_groups(pts, p, XY)
        errs.append((x - x0, y - y0, k / K - 1))
    e = np.asarray(errs)
    # the spread matches the least-squares prediction (400 trials: +-15 % covers it) ...
    assert np.std(e[:, 0]) == pytest.approx(sx, rel=0.15)
    assert np.std(e[:, 1]) == pytest.approx(sy, rel=0.15)
    # ... with no bias beyond the noise (first-order unbiased; 4 sigma of the mean)
    assert abs(np.mean(e[:, 0])) < 4 * sx / math.sqrt(len(e)) + 1e-9
    assert abs(np.mean(e[:, 1])) < 4 * sy / math.sqrt(len(e)) + 1e-9
    # noise-free: exact
    p = np.exp(math.log(1e-3) - K * ((pts[:, 0] - x0) ** 2 + (pts[:, 1] - y0) ** 2))
    (x, y), (k,), lp0 = s2.fit_log_paraboloid_groups(pts, p, XY)
    assert x == pytest.approx(x0, abs=1e-12) and y == pytest.approx(y0, abs=1e-12)
    assert k == pytest.approx(K, rel=1e-9)
    assert lp0 == pytest.approx(math.log(1e-3), abs=1e-9)
    # the prior-curvature fit extrapolates from far away (first light, 18 um off)
    far = pts + np.array([18e-6, 0.0])
    p = np.exp(math.log(1e-3) - K * ((far[:, 0] - x0) ** 2 + (far[:, 1] - y0) ** 2))
    (x, y), _, _ = s2.fit_log_paraboloid_groups(far[:3], p[:3], XY, curvature=K)
    assert x == pytest.approx(x0, abs=1e-12) and y == pytest.approx(y0, abs=1e-12)
    # a valley or a line of points is no peak
    assert s2.fit_log_paraboloid_groups(pts, 1.0 / p, XY) is None
    assert s2.fit_log_paraboloid_groups(np.column_stack([pts[:, 0], np.full(5, 1e-6)]), p,
                                        XY) is None


def test_parameters_come_from_the_config_file_only():
    seq = s2d.Sequencer2D(period_s=graph_period_s())
    assert seq.p == s2d.load_sequencer2d_params()
    with pytest.raises(ValueError, match='unknown'):
        s2d.Sequencer2D(period_s=1e-3, not_a_parameter=1.0)
    p = s2d.load_sequencer2d_params()
    del p['dither_radius_m']
    with pytest.raises(ValueError, match='missing'):
        s2d.Sequencer2D(p, period_s=1e-3)
    # the period is the caller's (1 / the graph's rate_hz): the core reads no file for it
    with pytest.raises(ValueError, match='period_s'):
        s2d.Sequencer2D()


def test_the_search_walks_no_faster_than_the_realtime_path_follows():
    # realtime: the loop follows a setpoint at most at realtime_setpoint_rate_m_per_s; a
    # spiral walked faster lags further each period until the follow check faults
    rate = 2.0e-3
    free = s2d.Sequencer2D(period_s=1e-3)
    bound = s2d.Sequencer2D(period_s=1e-3, path_rate_m_per_s=rate)
    assert free.search_speed == free.p['search_speed_m_per_s'] > rate
    assert bound.search_speed == pytest.approx(s2d.PATH_RATE_SHARE * rate)
    assert bound.search_speed < rate
    # the spiral's pitch is laid out for the chord walked between two readings
    p = bound.p
    chord = (int(p['confirm_samples']) + 1) * bound.search_speed * 1e-3
    assert bound.pitch_m == pytest.approx(
        s2.spiral_pitch(p['mode_radius_m'], p['spiral_capture_db'], chord))
    assert bound.pitch_m != free.pitch_m
    slow = s2d.Sequencer2D(period_s=1e-3, path_rate_m_per_s=1.0,
                           search_speed_m_per_s=1e-3)
    assert slow.search_speed == 1e-3           # a slower search is left as it is


def _bench2d(seed=2, **seq):
    from fiber_align.simulation import alignment2d_scenarios as sc
    bench = sc.build(seed=seed, seq_overrides=seq)
    for _ in range(20):
        bench.step()
    return bench


def _run_until(bench, states, max_s=2.0):
    for _ in range(int(max_s / bench.period_s)):
        if bench.seq.state in states:
            return True
        bench.step()
    return bench.seq.state in states


@pytest.mark.parametrize('trip_in', [s2d.SEARCHING, s2d.TRACKING])
def test_a_driver_held_mid_align_holds_the_setpoints_then_goes_on_to_tracking(trip_in):
    # a watchdog trip of one axis (drive_held true for 50 ms) while searching or tracking:
    # HELD with the setpoints kept, then a new search or a re-peak, and TRACKING at the peak
    bench = _bench2d()
    seq = bench.seq
    assert seq.align()[0]
    if trip_in == s2d.TRACKING:
        assert _run_until(bench, (s2d.TRACKING,)), seq.fault_reason
        for _ in range(50):
            bench.step()
    else:
        for _ in range(30):
            bench.step()
    assert seq.state == trip_in
    seq.driver_held(True, s2d.DRIVERS[1])
    assert seq.state == s2d.HELD and 'y/actuator_driver' in seq.status()['hold_reason']
    held = seq.setpoint
    for _ in range(50):
        bench.step()
        assert seq.state == s2d.HELD and seq.setpoint == held
    seq.driver_held(False, s2d.DRIVERS[1])
    bench.step()
    assert seq.state in (s2d.HELD, s2d.SEARCHING if trip_in == s2d.SEARCHING else s2d.PEAKING)
    assert _run_until(bench, (s2d.TRACKING, s2d.FAULT)), seq.state
    assert seq.state == s2d.TRACKING, seq.fault_reason
    for _ in range(20):
        bench.step()
    assert bench.true_loss() < 0.1


def test_a_driver_that_stays_down_ends_in_fault_with_the_reason():
    bench = _bench2d(driver_down_timeout_s=0.1)
    seq = bench.seq
    assert seq.align()[0]
    for _ in range(30):
        bench.step()
    seq.driver_held(True, s2d.DRIVERS[0])
    assert seq.state == s2d.HELD
    for _ in range(int(0.09 / bench.period_s)):
        bench.step()
    assert seq.state == s2d.HELD
    assert _run_until(bench, (s2d.FAULT,), 0.05)
    assert seq.fault_reason.startswith('driver inactive: a driver held its output for more '
                                       'than 0.1 s'), seq.fault_reason
    assert 'x/actuator_driver' in seq.fault_reason
