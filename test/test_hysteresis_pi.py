# SPDX-License-Identifier: Apache-2.0
"""Tests of the PI model core: play operators, state, invertibility, exact inverse."""

import numpy as np
import pytest

from fiber_align.hysteresis import data
from fiber_align.hysteresis.pi import (InversePIModel, NotInvertibleError, paper_model, PIModel,
                                       play_operators)

# The paper's Table 4 ("inverse model"): thresholds printed as 0, 8, ..., 72 and these
# weights (1/(um/V) = V/um).
TABLE4_WEIGHTS_V_PER_UM = [2.2536, -1.1126, -0.0251, -0.0238, 0.0071,
                           0.0225, -0.0158, -0.0059, 0.0020, 0.0047]


def _reference_play(u, r, state):
    """Play operators sample by sample, the textbook way."""
    y = state.copy()
    out = []
    for uk in u:
        y = np.maximum(uk - r, np.minimum(uk + r, y))
        out.append(y.copy())
    return np.array(out), y


def _random_path(rng, lo, hi, n=1500, knots=40):
    """Return a random piecewise-linear path between lo and hi (m)."""
    k = np.sort(rng.choice(np.arange(1, n - 1), knots - 2, replace=False))
    k = np.concatenate([[0], k, [n - 1]])
    return np.interp(np.arange(n), k, rng.uniform(lo, hi, knots))


@pytest.mark.parametrize('noisy', [False, True])
def test_play_operators_match_textbook_loop(noisy):
    rng = np.random.default_rng(3)
    u = np.concatenate([np.linspace(0, 72, 400), np.linspace(72, 10, 300),
                        np.full(5, 10.0), np.linspace(10, 60, 200)])
    if noisy:
        u = u + rng.normal(0, 0.3, u.size)
    r = np.sort(rng.uniform(0, 40, (4, 10)), axis=-1)
    state = rng.uniform(-5, 5, r.shape)
    got, final = play_operators(u, r, state)
    want, want_final = _reference_play(u, r, state)
    assert got.shape == (u.size, 4, 10)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(final, want_final)


def test_step_updates_state_and_matches_simulate():
    m = paper_model()
    _, u = data.experiment_signal(n_samples=501)
    y_sim = m.simulate(u)
    s_sim = m.state
    m.reset()
    y_step = np.array([m.step(x) for x in u])
    np.testing.assert_allclose(y_step, y_sim, rtol=0, atol=1e-18)
    np.testing.assert_array_equal(m.state, s_sim)
    assert np.any(m.state != 0.0)
    m.reset()
    assert np.all(m.state == 0.0)


def test_table3_loop_peaks_at_65_7_um():
    _, u = data.experiment_signal()
    y = paper_model().simulate(u)
    assert abs(y.max() - 65.7e-6) <= 0.2e-6


def test_refuses_non_invertible_weights_naming_the_index():
    with pytest.raises(NotInvertibleError, match='first bad index 3'):
        PIModel([0, 1, 2, 3], [1e-6, -0.5e-6, -0.6e-6, 1e-6])
    with pytest.raises(ValueError, match='strictly increasing'):
        PIModel([0, 2, 1], [1e-6, 0, 0])
    with pytest.raises(ValueError, match='first threshold must be 0'):
        PIModel([1, 2], [1e-6, 0])


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_inverse_round_trip_is_exact(seed):
    rng = np.random.default_rng(seed)
    m = paper_model()
    # Leave the model in a non-rest state, then invert from that state.
    m.simulate(np.concatenate([np.linspace(0, 72, 300), np.linspace(72, 25, 200)]))
    inv = m.inverse()
    lo, hi = m.loading_curve(2.0), m.loading_curve(60.0)
    yref = _random_path(rng, lo, hi)
    u = inv.simulate(yref)
    y = m.simulate(u, reset=False)
    assert np.max(np.abs(y - yref)) < 1e-12
    # step-by-step gives the same
    inv.reset()
    assert np.allclose([inv.step(v) for v in yref], u, rtol=0, atol=1e-9)


def test_inverse_round_trip_random_models():
    rng = np.random.default_rng(7)
    for _ in range(5):
        r = np.concatenate([[0.0], np.sort(rng.uniform(1, 70, 7))])
        s = rng.uniform(0.2e-6, 1.5e-6, 8)           # positive partial sums
        m = PIModel(r, np.diff(s, prepend=0.0))
        yref = _random_path(rng, 0.0, m.loading_curve(70.0), n=800)
        y = m.simulate(m.inverse().simulate(yref))
        assert np.max(np.abs(y - yref)) < 1e-12


def test_table4_of_the_paper_is_not_the_inverse():
    m = paper_model()
    yref = _random_path(np.random.default_rng(0), 2e-6, 60e-6)
    w4 = np.array(TABLE4_WEIGHTS_V_PER_UM) * 1e6
    exact = m.inverse()
    # The first two printed weights agree with the formula, the rest do not.
    np.testing.assert_allclose(exact.weights[:2], w4[:2], rtol=1e-3)
    assert np.max(np.abs(exact.weights[2:] - w4[2:]) / np.abs(w4[2:])) > 0.5
    for thresholds in (m.thresholds * 1e-6, exact.thresholds):
        bad = InversePIModel(thresholds, w4)
        err = np.max(np.abs(m.simulate(bad.simulate(yref)) - yref))
        assert err > 1e-6


def test_save_and_load_round_trip(tmp_path):
    m = paper_model()
    p = tmp_path / 'model.yaml'
    m.save(p)
    m2 = PIModel.load(p)
    np.testing.assert_array_equal(m2.thresholds, m.thresholds)
    np.testing.assert_array_equal(m2.weights, m.weights)
