# SPDX-License-Identifier: Apache-2.0
"""The fast paths of the control core equal the plain computations they replace."""

import math

import numpy as np
import pytest

from fiber_align.config import load_params
from fiber_align.control.feedforward import Feedforward
from fiber_align.control.fuzzy import FuzzyInference
from fiber_align.control.fuzzy_surface import FuzzySurface, surface_error_bound
from fiber_align.control.shaping import design, Lead, Shaper
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics, discretise
from fiber_align.hysteresis.pi import paper_model, PIModel
from fiber_align.hysteresis.playbank import PlayBank
from fiber_align.hysteresis.truth import make_hysteresis


def _fis():
    """Return the configured fuzzy system and its surface setting."""
    fz = load_params('controller.yaml', 'fuzzy_pid_controller')['fuzzy']
    return FuzzyInference.from_params(fz), int(fz['surface_intervals'])


def _drive(scale, seed=0):
    """Return a test input: growing sine, noisy hold (a reversal every sample), walk."""
    rng = np.random.default_rng(seed)
    return np.concatenate([
        scale * np.sin(np.linspace(0, 20, 3000)) * np.linspace(0, 1.2, 3000),
        0.5 * scale + 0.01 * scale * rng.standard_normal(2000),
        np.cumsum(rng.standard_normal(3000)) * 0.02 * scale]).tolist()


@pytest.mark.parametrize('kind', ['dense-pi', 'paper'])
@pytest.mark.parametrize('inverse', [False, True])
def test_playbank_equals_operator_by_operator_pi(kind, inverse):
    """The PlayBank gives the PI (or inverse PI) output to rounding and the same states."""
    law = make_hysteresis(kind) if kind == 'dense-pi' else paper_model()
    law.reset()
    model = law.inverse() if inverse else law
    bank = PlayBank(model.thresholds, model.weights)
    u = _drive(70e-6 if inverse else 80.0)
    ref = [model.step(x) for x in u]
    fast = [bank.step(x) for x in u]
    span = max(abs(x) for x in ref)
    assert max(abs(a - b) for a, b in zip(ref, fast)) <= 1e-12 * span
    np.testing.assert_allclose(bank.state, model.state, rtol=0, atol=1e-12 * max(u))


def test_playbank_from_a_non_rest_state_and_bad_state():
    """A bank started from a model's non-rest state follows it; a non-memory state fails."""
    m = PIModel([0.0, 10.0, 20.0], [0.5e-6, 0.3e-6, 0.2e-6])
    for x in (40.0, 5.0, 25.0):
        m.step(x)
    bank = PlayBank.from_model(m)
    for x in (30.0, 12.0, 12.5, 50.0, -3.0):
        assert bank.step(x) == pytest.approx(m.step(x), rel=1e-14, abs=1e-20)
    with pytest.raises(ValueError):
        PlayBank([0.0, 1.0], [1.0, 1.0], state=[0.0, 5.0])


def test_fuzzy_surface_error_is_proven_below_1e3_of_span():
    """The configured surface's proven bound is < 1e-3 of each span and holds on samples."""
    fis, q = _fis()
    bound = surface_error_bound(fis, q)
    assert np.all(bound < 1e-3), bound
    # the bound shrinks as 1/q^2 (the pieces are smooth: no kink inside a triangle)
    assert surface_error_bound(fis, q // 2) / bound == pytest.approx(4.0, rel=0.1)
    surf = FuzzySurface(fis, q)
    spans = np.array([hi - lo for lo, hi in fis.out_domains])
    rng = np.random.default_rng(11)
    pts = list(rng.uniform([-13.0, -21.0], [13.0, 21.0], (1500, 2)))
    # near the steep corners of rule cells and on the kink lines
    for e0 in np.linspace(-12.0, 12.0, 7):
        for c0 in np.linspace(-20.0, 20.0, 7):
            pts += list(np.array([e0, c0]) + rng.uniform(-0.3, 0.3, (6, 2)))
    worst = np.zeros(3)
    for e, ec in pts:
        err = np.abs(np.array(surf.evaluate(e, ec)) - np.array(fis.evaluate(e, ec))) / spans
        worst = np.maximum(worst, err)
    assert np.all(worst <= bound), (worst, bound)


def test_fuzzy_area_moment_vectorised_equals_scalar():
    """The vectorised area/moment equals the scalar one (used to build the surface)."""
    fis, _ = _fis()
    rng = np.random.default_rng(5)
    p = rng.uniform([-13.0, -21.0], [13.0, 21.0], (300, 2))
    g = fis.area_moment_grid(p[:, 0], p[:, 1])
    for k, (e, ec) in enumerate(p):
        for o, (a, m) in enumerate(fis.area_moment(e, ec)):
            assert g[o, 0, k] == pytest.approx(a, abs=1e-13)
            assert g[o, 1, k] == pytest.approx(m, abs=1e-13)


@pytest.mark.parametrize('rate', [1000.0, 10000.0])
def test_lead_does_not_extrapolate_steps_but_predicts_smooth_references(rate):
    """Steps of any size add <= lead a T; a ramp and a triangle corner are predicted."""
    t = 1.0 / rate
    lead_s, acc = 3 * t, 0.01
    for size in (1e-9, 1e-7, 5e-6, 45e-6, 82e-6):
        for start in (0.0, 20e-6):
            ld = Lead(t, lead_s, acc)
            ld.reset(start)
            out = [ld.step(start + size) for _ in range(5)]
            assert out[0] - (start + size) <= lead_s * acc * t * (1 + 1e-9)
            assert out[1:] == [start + size] * 4
    ld = Lead(t, lead_s, acc)
    speed = 164e-6                      # m/s, the 1 Hz 0..82 um triangle
    ramp = [speed * k * t for k in range(2000)]
    out = [ld.step(r) for r in ramp]
    assert out[-1] == pytest.approx(ramp[-1] + lead_s * speed, rel=1e-9)
    down = [ramp[-1] - speed * k * t for k in range(1, 5)]
    assert [ld.step(r) for r in down] == pytest.approx([r - lead_s * speed for r in down],
                                                       rel=1e-9)


@pytest.mark.parametrize('rate', [1000.0, 10000.0])
def test_a_bounded_lead_never_predicts_past_the_target_of_the_path(rate):
    """A rate-limited path to a target: predicted exactly mid-way, never past the target."""
    t = 1.0 / rate
    lead_s, speed = 3 * t, 2e-3     # the acceleration limit far off: the rate is followed
    for lo, hi in ((0.0, 80e-6), (60e-6, 5e-6)):
        ld = Lead(t, lead_s, 1e3)
        ld.reset(lo)
        ld.toward = hi
        n = int(round(abs(hi - lo) / (speed * t)))
        path = [lo + (hi - lo) * k / n for k in range(1, n)] + [hi] * 5
        out = [ld.step(r) for r in path]
        assert min(lo, hi) <= min(out) and max(out) <= max(lo, hi)
        # away from the end, the ramp is predicted as without the bound
        mid = n // 2
        assert out[mid] == pytest.approx(path[mid] + lead_s * (hi - lo) / (n * t), rel=1e-6)
        assert out[-1] == hi
    # a path that reverses: the prediction turns at once and stays within the targets
    ld = Lead(t, lead_s, 1e3)
    ld.reset(40e-6)
    ld.toward = 0.0
    r, outs = 40e-6, []
    for k in range(200):
        ld.toward = 0.0 if (k // 7) % 2 == 0 else 80e-6
        r = max(0.0, r - speed * t) if ld.toward == 0.0 else min(80e-6, r + speed * t)
        outs.append(ld.step(r))
    assert 0.0 <= min(outs) and max(outs) <= 80e-6
    ld.toward = None                    # unbounded again: the plain prediction
    assert ld.step(r + speed * t) == pytest.approx(r + speed * t + lead_s * speed, rel=1e-6)


def test_unrolled_shaper_equals_the_tap_sum():
    """The unrolled three-tap shaper is bit-identical to the plain FIR sum over all taps."""
    wn, _ = design_dynamics(load_actuator())
    for t in (1e-3, 1e-4):
        taps = design('zv', wn, 0.03, t)
        sh = Shaper(taps)
        assert sh._zv is not None
        rng = np.random.default_rng(2)
        r = np.concatenate([np.full(50, 45e-6), rng.uniform(0, 80e-6, 100)]).tolist()
        hist = [0.0] * len(taps)
        for x in r:
            hist = [x] + hist[:-1]
            s = 0.0
            for h, v in zip(sh.taps, hist):
                s += h * v
            assert sh.step(x) == s


def test_closed_form_discretisation_equals_expm():
    """The closed-form ZOH discretisation equals scipy's matrix exponential."""
    from scipy.linalg import expm
    for wn, z, t in ((8741.0, 0.03, 1e-3), (8741.0, 0.03, 1e-4), (50.0, 0.7, 0.01)):
        ad, bd = discretise(wn, z, t)
        a = np.array([[0, 1, 0], [-wn ** 2, -2 * z * wn, wn ** 2], [0, 0, 0]]) * t
        m = expm(a)
        np.testing.assert_allclose(ad, m[:2, :2], rtol=1e-12, atol=1e-12 * wn)
        np.testing.assert_allclose(bd, m[:2, 2], rtol=1e-12, atol=1e-12 * wn)


def test_feedforward_start_at_holds_without_transient():
    """start_at(r) settles the compensator at r: the next periods give the same voltage."""
    wn, _ = design_dynamics(load_actuator())
    t = 1e-3
    ff = Feedforward(paper_model(), shaper=Shaper(design('zv', wn, 0.03, t)),
                     lead=Lead(t, 2 * t, 0.01))
    u0 = ff.start_at(40e-6)
    assert [ff.step(40e-6) for _ in range(5)] == pytest.approx([u0] * 5, rel=1e-12)
    assert math.isfinite(u0) and u0 > 0
