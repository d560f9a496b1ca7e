# SPDX-License-Identifier: Apache-2.0
"""Tests of the reference ("true") hysteresis laws used by the simulated plant."""

import numpy as np
import pytest

from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics
from fiber_align.hysteresis import data
from fiber_align.hysteresis.truth import BoucWen, make_hysteresis

ALPHA_M_PER_V = design_dynamics(load_actuator())[1]


def _law(kind):
    """Return the law ``kind``; ``linear`` with the design model's slope (m/V), as the plant."""
    return make_hysteresis(kind, alpha_m_per_v=ALPHA_M_PER_V if kind == 'linear' else None)


def _loop(h, n=1001):
    """Return (peak, width/peak) of the 0-72 V triangle loop of ``h``."""
    u = np.concatenate([np.linspace(0, 72, n), np.linspace(72, 0, n)[1:]])
    y = h.simulate(u)
    asc, desc = y[:n], y[n - 1:][::-1]
    return y.max(), np.max(desc - asc) / y.max()


@pytest.mark.parametrize('kind', ['dense-pi', 'bouc-wen'])
def test_rich_laws_are_calibrated_like_the_measured_loop(kind):
    peak, width = _loop(make_hysteresis(kind))
    assert abs(peak - 70e-6) < 0.5e-6
    assert 0.10 <= width <= 0.15


@pytest.mark.parametrize('kind', ['dense-pi', 'bouc-wen', 'linear'])
def test_monotone_up_to_100_v(kind):
    h = _law(kind)
    up = np.linspace(0, 100, 801)
    u = np.concatenate([up, up[::-1][1:], up[1:] * 0.6])
    y = h.simulate(u)
    n = up.size
    assert np.all(np.diff(y[:n]) > 0)
    assert np.all(np.diff(y[n - 1:2 * n - 1]) < 0)
    assert np.all(np.diff(y[2 * n - 1:]) > 0)
    assert y.max() < 200e-6 and y[n - 1] > 90e-6


@pytest.mark.parametrize('kind', ['dense-pi', 'bouc-wen', 'paper', 'linear'])
def test_step_matches_simulate_and_reset(kind):
    h = _law(kind)
    _, u = data.experiment_signal(n_samples=301)
    y = h.simulate(u)
    h.reset()
    ys = np.array([h.step(x) for x in u])
    np.testing.assert_allclose(ys, y, rtol=0, atol=1e-15)
    h.reset()
    assert h.step(0.0) == 0.0


def test_bouc_wen_is_rate_independent_and_exact_at_any_sampling():
    bw = make_hysteresis('bouc-wen')
    coarse = np.array([0.0, 72.0, 30.0, 50.0, 0.0])
    fine = np.concatenate([np.linspace(a, b, 2001)[:-1] for a, b in zip(coarse, coarse[1:])]
                          + [[0.0]])
    y_c = bw.simulate(coarse)
    y_f = bw.simulate(fine)
    idx = np.arange(0, fine.size, 2000)
    np.testing.assert_allclose(y_f[idx], y_c, rtol=0, atol=1e-15)


def test_bad_kind_and_bad_bouc_wen_parameters():
    with pytest.raises(ValueError, match='allowed: dense-pi'):
        make_hysteresis('preisach')
    with pytest.raises(ValueError, match=r'\|g\| <= b'):
        BoucWen(1e-6, 0.3, 0.01, 0.02)


def test_paper_kind_is_table3():
    h = make_hysteresis('paper')
    assert h.n == 10 and abs(h.weights[0] - 0.4437e-6) < 1e-15


def test_linear_law_needs_the_design_slope():
    """No silent default slope: the caller passes the design model's alpha (m/V)."""
    with pytest.raises(ValueError, match='alpha_m_per_v'):
        make_hysteresis('linear')
    assert make_hysteresis('linear', alpha_m_per_v=ALPHA_M_PER_V).step(10.0) == \
        ALPHA_M_PER_V * 10.0
