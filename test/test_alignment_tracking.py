# SPDX-License-Identifier: Apache-2.0
"""
TRACKING's one law (:mod:`fiber_align.alignment.tracking`): demodulator, tracker, lost power.

``JointDemodulator(n)`` for one circle (the 2-D sequencer's) and two at distinct frequencies
(the station's); the :class:`~fiber_align.alignment.tracking.Tracker`'s dither shapes and
its climb to the peak; the lost-power rule (the estimate holds, the dither goes on, FAULT
after ``track_loss_timeout_s``).
"""

import math

import numpy as np
import pytest

from fiber_align.alignment import sequencer as sq
from fiber_align.alignment.tracking import JointDemodulator, LossWatch, Tracker
from fiber_align.plant import optics as op

W = 5.2e-6
K = 1.0 / W ** 2                  # curvature of ln P (1/m^2), no gap


@pytest.mark.parametrize('lag_deg', [0.0, 40.0])
def test_two_axis_circle_demodulation_points_uphill(lag_deg):
    """The gradient points at the peak, magnitude 2 k |offset|, whatever the loop's lag."""
    x0, y0 = 20e-6, 30e-6
    a, f, dt = 0.3e-6, 50.0, 1e-3
    for ang in np.radians([0.0, 75.0, 130.0, 250.0]):
        off = 0.6e-6
        cx, cy = x0 - off * math.cos(ang), y0 - off * math.sin(ang)   # peak at +ang
        det = op.Detector(noise_floor_w=0.0, rin_db=0.0, seed=0)
        dm = JointDemodulator(2, 0.04, lag_s=det.lag_s(dt))
        for k in range(200):
            # the tip follows the commanded circle with a phase lag and 80 % amplitude
            ph = 2 * math.pi * f * k * dt - math.radians(lag_deg)
            x = cx + 0.8 * a * math.cos(ph)
            y = cy + 0.8 * a * math.sin(ph)
            pw = det.measure(1e-3 * math.exp(-K * ((x - x0) ** 2 + (y - y0) ** 2)), dt)
            dm.update(dt, (x, y), math.log(pw))
        gx, gy = dm.gradient(0.01 * a * a)
        err = math.degrees(math.atan2(math.sin(math.atan2(gy, gx) - ang),
                                      math.cos(math.atan2(gy, gx) - ang)))
        assert abs(err) < 2.0
        assert math.hypot(gx, gy) == pytest.approx(2 * K * off, rel=0.05)


def test_joint_demodulator_separates_two_circles_at_distinct_frequencies():
    g = np.array([0.3e6, -0.2e6, 0.1e6, 0.4e6])        # d ln P / d pos, 1/m
    a, dt = 0.1e-6, 1e-3
    dem = JointDemodulator(4, 0.05)
    for k in range(400):
        t = k * dt
        pos = a * np.array([math.cos(2 * math.pi * 100 * t), math.sin(2 * math.pi * 100 * t),
                            math.cos(2 * math.pi * 80 * t), math.sin(2 * math.pi * 80 * t)])
        dem.update(dt, pos, -2.0 + float(g @ pos))
    assert np.allclose(dem.gradient(0.1 * a * a), g, rtol=1e-6)
    same = JointDemodulator(4, 0.05)
    for k in range(400):
        ph = 2 * math.pi * 100 * k * dt
        pos = a * np.array([math.cos(ph), math.sin(ph), math.cos(ph), math.sin(ph)])
        same.update(dt, pos, float(g @ pos))
    assert same.gradient(0.1 * a * a) is None          # one frequency: not separable


def _tracker(center, dithers, lo=0.0, hi=65e-6):
    p = sq.Sequencer().p
    n = len(center)
    return Tracker(center, K, 0.1e-6, dithers, 0.0, p, np.full(n, lo), np.full(n, hi),
                   1e-3), p


def test_the_dithers_are_a_sine_on_a_lone_axis_and_a_circle_on_a_pair():
    tr, _ = _tracker([10e-6, 20e-6, 30e-6], [(50.0, (0,)), (80.0, (1, 2))])
    t = 0.0031
    off = tr.offset(t)
    assert off[0] == pytest.approx(0.1e-6 * math.sin(2 * math.pi * 50.0 * t), abs=1e-18)
    assert off[1] == pytest.approx(0.1e-6 * math.cos(2 * math.pi * 80.0 * t), abs=1e-18)
    assert off[2] == pytest.approx(0.1e-6 * math.sin(2 * math.pi * 80.0 * t), abs=1e-18)


@pytest.mark.parametrize('n', [1, 2])
def test_the_tracker_climbs_to_the_peak_at_its_bandwidth(n):
    """Readings of a Gaussian peak 0.3 um off: the estimate moves onto it (ideal tip)."""
    peak = np.full(n, 30.3e-6)
    dithers = [(50.0, (0,))] if n == 1 else [(50.0, (0, 1))]
    tr, p = _tracker(np.full(n, 30e-6), dithers)
    dt, sp = 1e-3, tr.xhat + tr.offset(0.0)
    for k in range(1, 1500):
        pw = 1e-3 * math.exp(-K * float(np.sum((sp - peak) ** 2)))
        sp = tr.step(k * dt, dt, sp, pw)
    # 1.5 s at 20 rad/s: many time constants; the residual is the dither's bias (none)
    assert np.all(np.abs(tr.xhat - peak) < 0.02e-6), (tr.xhat - peak)


def test_lost_power_holds_the_estimate_keeps_the_dither_then_faults():
    tr, p = _tracker([30e-6], [(50.0, (0,))])
    low = 1e-3 * 10 ** (-p['track_loss_db'] / 10.0)
    x0 = tr.xhat.copy()
    t, dt = 0.1, 1e-3
    sps = []
    while t < 0.1 + p['track_loss_timeout_s'] - 1e-9:
        sp = tr.step(t, dt, tr.xhat, 0.5 * low)
        assert sp is not None and tr.loss.fault == ''
        sps.append(sp[0])
        t += dt
    assert np.all(tr.xhat == x0)                        # the estimate holds ...
    assert np.ptp(sps) > 0.1e-6                         # ... the dither goes on
    assert tr.step(t + 2 * dt, dt, tr.xhat, 0.5 * low) is None
    assert tr.loss.fault.startswith('power lost while tracking')
    watch = LossWatch(1e-3, 10.0, 0.02)
    assert watch.lost(0.0, 0.5e-4) and not watch.lost(0.001, None) and watch.since == 0.0
    assert not watch.lost(0.002, 0.5e-3) and watch.since is None   # a good reading resets


@pytest.mark.parametrize('n', [1, 2, 3, 4, 6])
def test_the_demodulator_is_the_numpy_regression_it_replaced(n):
    """Plain floats, the same figures as the numpy formulas (running means, cov, solve)."""
    rng = np.random.default_rng(n)
    dem = JointDemodulator(n, 0.05, lag_s=0.16e-3)
    m, cov, cross, prev = None, np.zeros((n, n)), np.zeros(n), None
    for k in range(300):
        dt = 1e-3 * (1.0 + 0.5 * rng.random())
        pos = 1e-7 * rng.standard_normal(n)
        lnp = -2.0 + float(rng.standard_normal())
        dem.update(dt, pos if n > 1 else float(pos[0]), lnp)
        lagged = pos if prev is None else pos - min(1.0, 0.16e-3 / dt) * (pos - prev)
        prev, v = pos, np.append(lagged, lnp)
        if m is None:
            m = v
            continue
        a = min(1.0, dt / 0.05)
        d = v - m
        m = m + a * d
        cov = (1.0 - a) * (cov + a * np.outer(d[:-1], d[:-1]))
        cross = (1.0 - a) * (cross + a * d[:-1] * d[-1])
    assert np.allclose(dem.cov, cov, rtol=1e-12, atol=0)
    assert np.allclose(dem.gradient(1e-20), np.linalg.solve(cov, cross), rtol=1e-9)
    assert dem.gradient(1.0) is None                    # a variance below the bound
