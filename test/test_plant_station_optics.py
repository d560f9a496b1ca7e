# SPDX-License-Identifier: Apache-2.0
"""The station's optics: the Gaussian overlap against a numerical integral, the chip link."""

import math

import numpy as np
import pytest

from fiber_align.plant import optics as op
from fiber_align.plant import station_optics as so


def numerical_overlap(w1, w2, d, half=25e-6, n=1001):
    """Return ``|int E1 E2 dA|^2 / (int E1^2 dA int E2^2 dA)`` on an n x n grid (m)."""
    x = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(x, x)
    e1 = np.exp(-(xx ** 2 + yy ** 2) / w1 ** 2)
    e2 = np.exp(-((xx - d) ** 2 + yy ** 2) / w2 ** 2)
    da = (x[1] - x[0]) ** 2
    return (np.sum(e1 * e2) * da) ** 2 / (np.sum(e1 ** 2) * da * np.sum(e2 ** 2) * da)


@pytest.mark.parametrize('w2', [1.5e-6, 2.6e-6, 4.0e-6])
@pytest.mark.parametrize('d', [0.0, 0.7e-6, 2.0e-6, 4.5e-6])
def test_overlap_formula_equals_the_numerical_overlap_integral(w2, d):
    w1 = 2.6e-6
    num = numerical_overlap(w1, w2, d)
    # the grid reaches 5 waists past both modes at 50 nm steps: the truncation and the
    # rectangle rule are far below this relative tolerance
    assert so.mode_overlap(d, w1, w2) == pytest.approx(num, rel=1e-6, abs=1e-12)


def test_equal_modes_reduce_to_the_fiber_to_fiber_model():
    w = 5.2e-6
    d = np.linspace(0, 10e-6, 11)
    assert np.allclose(so.mode_overlap(d, w, w), op.coupling_efficiency(d, 0.0, w))
    assert so.mode_overlap(0.0, w, 2 * w) < 1.0                 # mismatch costs at d = 0


def test_link_power_is_the_product_of_both_facets_and_the_chip():
    link = so.StationLink.from_params(seed=0, noise_floor_w=0.0, rin_db=0.0,
                                      averaging_time_s=0.0)
    c = link.coupling
    pk = c.peak(0.0)
    eta0 = so.mode_overlap(0.0, 2.6e-6, 1.5e-6)
    assert c.max_power_w() == pytest.approx(1e-3 * eta0 ** 2 * 10 ** (-0.3))
    assert c.power_w(0.0, pk) == pytest.approx(c.max_power_w())
    pos = (pk[0] + 1e-6, pk[1], pk[2], pk[3] - 0.5e-6)
    want = c.max_power_w() * so.mode_overlap(1e-6, 2.6e-6, 1.5e-6) / eta0 * \
        so.mode_overlap(0.5e-6, 2.6e-6, 1.5e-6) / eta0
    assert c.power_w(0.0, pos) == pytest.approx(want)
    # ln P is a separable paraboloid: the losses of the two sides add in dB
    k = c.curvature_per_m2
    assert c.loss_db(0.0, pos) == pytest.approx(10 / math.log(10) * k * (1e-12 + 0.25e-12))
    assert link.measure(0.0, pk) == pytest.approx(c.max_power_w())


def test_detector_noise_floor_and_rin_are_the_shared_detector():
    link = so.StationLink.from_params(seed=3)
    ref = op.load_optics(seed=3).detector
    d = link.detector
    assert isinstance(d, op.Detector)
    assert (d.noise_floor_w, d.rin_db, d.averaging_time_s) == (
        ref.noise_floor_w, ref.rin_db, ref.averaging_time_s)
    dark = np.array([link.measure(0.0, (0.0, 0.0, 65e-6, 65e-6)) for _ in range(2000)])
    assert 0.3 * d.noise_floor_w < dark.mean() < 1.5 * d.noise_floor_w


def test_cure_pulls_the_peak_smoothly_to_its_amplitude():
    cure = so.CureDrift(1.5e-6, math.pi / 2, 20.0, 1.0)
    assert cure.offset(0.5) == (0.0, 0.0)
    dx, dy = cure.offset(11.0)
    assert dx == pytest.approx(0.0, abs=1e-15) and dy == pytest.approx(0.75e-6)
    assert cure.offset(30.0)[1] == pytest.approx(1.5e-6)
    t = np.linspace(1.0, 21.0, 2001)
    v = np.diff(cure.offset(t)[1]) / np.diff(t)
    assert v.max() == pytest.approx(math.pi * 1.5e-6 / 40.0, rel=1e-3)   # peak speed
    c = so.StationLink.from_params(cure_in_amplitude_m=1e-6, cure_in_duration_s=10.0,
                                   cure_start_s=0.0).coupling
    p0, p1 = c.peak(0.0), c.peak(10.0)
    assert math.hypot(p1[0] - p0[0], p1[1] - p0[1]) == pytest.approx(1e-6)
    assert p1[2:] == p0[2:]


def test_unknown_or_missing_parameters_are_refused():
    with pytest.raises(ValueError, match='unknown station optics parameter'):
        so.StationLink.from_params(facet_x_m=1.0)
    with pytest.raises(ValueError, match='missing'):
        so.StationLink.from_params(station_params={'chip_loss_db': 1.0})
    with pytest.raises(ValueError):
        so.CureDrift(1e-6, 0.0, 0.0)


def test_per_period_and_array_paths_agree():
    link = so.StationLink.from_params(cure_out_amplitude_m=1e-6, cure_out_angle_rad=0.5,
                                      cure_out_duration_s=4.0, cure_start_s=1.0)
    c = link.coupling
    rng = np.random.default_rng(2)
    pos = rng.uniform(10e-6, 50e-6, (4, 50))
    t = rng.uniform(0.0, 6.0, 50)
    scalar = np.array([c.power_w(float(ti), tuple(float(v) for v in pos[:, i]))
                       for i, ti in enumerate(t)])
    ref = np.array([float(c.power_w(np.array([ti]), [pos[k, i:i + 1] for k in range(4)])[0])
                    for i, ti in enumerate(t)])
    assert np.allclose(scalar, ref, rtol=1e-12, atol=0)
    assert np.allclose(c.loss_db(t, pos),
                       [c.loss_db(float(ti), pos[:, i]) for i, ti in enumerate(t)])
