# SPDX-License-Identifier: Apache-2.0
"""The one optical link (fiber_align.plant.link): the overlap against an integral, N axes."""

import math

import numpy as np
import pytest

from fiber_align.plant import link as ln
from fiber_align.plant import optics as op


def numerical_overlap(w1, w2, gap, d, wavelength=1.55e-6, index=1.0, half=25e-6, n=1001):
    """
    Return the power overlap of mode 1 (waist ``w1``, propagated ``gap``) and mode 2 at ``d``.

    Mode 1 is the complex Gaussian ``exp(-i k r^2 / (2 q)) / q``, ``q = gap + i z_R``,
    ``z_R = pi n w1^2 / lambda``, ``k = 2 pi n / lambda`` (m); mode 2 a waist ``w2`` offset
    by ``d`` along x; ``|int E1 E2* dA|^2 / (int |E1|^2 dA int |E2|^2 dA)`` on an n x n grid.
    """
    x = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(x, x)
    k = 2.0 * math.pi * index / wavelength
    q = gap + 1j * math.pi * index * w1 ** 2 / wavelength
    e1 = np.exp(-1j * k * (xx ** 2 + yy ** 2) / (2.0 * q)) / q
    e2 = np.exp(-((xx - d) ** 2 + yy ** 2) / w2 ** 2)
    num = abs(np.sum(e1 * np.conj(e2))) ** 2
    return num / (np.sum(abs(e1) ** 2) * np.sum(abs(e2) ** 2))


@pytest.mark.parametrize('w1, w2, gap', [(2.6e-6, 1.5e-6, 4e-6), (5.2e-6, 5.2e-6, 10e-6),
                                         (2.6e-6, 4.0e-6, 0.0)])
@pytest.mark.parametrize('d', [0.0, 1.0e-6, 3.0e-6])
def test_overlap_with_gap_and_mismatch_equals_the_numerical_integral(w1, w2, gap, d):
    eta0, c = ln.overlap(w1, w2, gap)
    # 50 nm steps, 5 waists of margin: the grid error is far below this tolerance
    assert eta0 * math.exp(-c * d * d) == pytest.approx(numerical_overlap(w1, w2, gap, d),
                                                        rel=1e-6, abs=1e-12)


def test_one_facet_of_one_axis_is_the_fiber_to_fiber_model():
    # the 1-D model (optics.py: equal modes across a gap, a drifting, vibrating slot)
    kw = dict(source_power_w=2e-3, mode_radius_m=5.2e-6, gap_m=10e-6, slot_position_m=30e-6,
              slot_drift_m_per_s=1e-6, slot_vibration_amplitude_m=0.2e-6,
              slot_vibration_frequency_hz=30.0)
    ref = op.FiberCoupling(**kw)
    target = ln.Target((30e-6,), (1e-6,), 0.2e-6, 30.0)
    c = ln.Coupling(2e-3, [ln.Facet((0,), target, 5.2e-6, 5.2e-6, 10e-6)])
    t = np.linspace(0.0, 2.0, 41)
    x = np.linspace(20e-6, 45e-6, 41)
    assert np.allclose(c.power_at(t, (x,)), ref.power_w(t, x), rtol=1e-12, atol=0)
    assert c.power_at(0.7, (31e-6,)) == pytest.approx(ref.power_w(0.7, 31e-6), rel=1e-12)
    assert c.max_power_w() == pytest.approx(ref.max_power_w(), rel=1e-12)


def test_power_is_the_product_of_the_facets_and_the_transmission():
    w1, w2 = 2.6e-6, 1.5e-6
    pull = ln.CureDrift(1e-6, math.pi / 2, 2.0, 0.0)
    facets = [ln.Facet((0, 1), ln.Target((10e-6, 20e-6)), w1, w2),
              ln.Facet((2,), ln.Target((5e-6,), (1e-6,)), w1, w1, 3e-6),
              ln.Facet((3, 4), ln.Target((0.0, 0.0), pull=pull), w2, w2)]
    c = ln.Coupling(1e-3, facets, transmission=0.5)
    assert c.n_axes == 5
    t = 3.0                                        # the pull is complete: +1 um along y
    pk = c.peak(t)
    assert pk == pytest.approx((10e-6, 20e-6, 8e-6, 0.0, -1e-6), abs=1e-18)
    pos = (11e-6, 19.5e-6, 8.2e-6, 0.3e-6, -1e-6)
    want = 1e-3 * 0.5
    for f, d in zip(facets, (math.hypot(1e-6, 0.5e-6), 0.2e-6, 0.3e-6)):
        want *= f.eta0 * math.exp(-f.curvature_per_m2 * d * d)
    assert c.power_at(t, pos) == pytest.approx(want, rel=1e-12)
    arr = c.power_at(np.array([t]), [np.array([v]) for v in pos])
    assert arr[0] == pytest.approx(want, rel=1e-12)
    assert c.loss_at(t, pk) == pytest.approx(0.0, abs=1e-12)
    c.fiber_broken = True
    assert c.power_at(t, pos) == 0.0 and c.max_power_w() == 0.0


def test_bad_links_are_refused():
    with pytest.raises(ValueError):
        ln.overlap(0.0, 1e-6)
    with pytest.raises(ValueError):
        ln.overlap(1e-6, 1e-6, gap_m=-1e-6)
    with pytest.raises(ValueError, match='a target of 1 axes for a facet of 2'):
        ln.Facet((0, 1), ln.Target((0.0,)), 1e-6, 1e-6)
    with pytest.raises(ValueError, match='unknown rig parameter'):
        ln.split_overrides({'slot_x': 1.0}, ((('a',), {}),), 'rig')
