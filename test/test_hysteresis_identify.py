# SPDX-License-Identifier: Apache-2.0
"""Tests of PI identification: lsq, the paper's PSO, PSO over thresholds, bad data, CLI."""

import json

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from fiber_align.cli import main as cli_main
from fiber_align.hysteresis import data
from fiber_align.hysteresis.identify import (bounded_lsq, bounded_lsq_batch, identify,
                                             paper_thresholds, partial_sum_basis)
from fiber_align.hysteresis.pi import paper_model, play_operators
from fiber_align.hysteresis.truth import make_hysteresis

NOISE_M = 10e-9


def _data(kind, v_max=72.0, n=2001, noise=NOISE_M, seed=0):
    """Return (t, u, y) of the 0.1 Hz triangle through a truth law plus noise (s, V, m)."""
    t, u = data.experiment_signal(v_max=v_max, n_samples=n)
    y = make_hysteresis(kind).simulate(u)
    return t, u, y + np.random.default_rng(seed).normal(0.0, noise, u.size)


@pytest.fixture(scope='module')
def rich():
    """Make data of the two richer laws and their lsq fits."""
    out = {}
    for kind in ('dense-pi', 'bouc-wen'):
        t, u, y = _data(kind)
        out[kind] = (t, u, y, identify(t, u, y, 'lsq'))
    return out


def test_lsq_recovers_table3_weights():
    truth = paper_model()
    # 0-80 V so that the 72 V operator is active too (on 0-72 V it never is).
    t, u, y = _data('paper', v_max=80.0)
    res = identify(t, u, y, 'lsq', thresholds=truth.thresholds)
    assert np.max(np.abs(res.model.weights - truth.weights)) < 1e-9
    assert 0.9 * NOISE_M < res.rms_error_m < 1.1 * NOISE_M


def test_lsq_on_the_0_72_v_experiment_refuses_the_idle_72_v_operator():
    truth = paper_model()
    t, u, y = _data('paper')
    with pytest.raises(ValueError, match='operator 10 .* never active'):
        identify(t, u, y, 'lsq', thresholds=truth.thresholds)
    res = identify(t, u, y, 'lsq', thresholds=truth.thresholds[:9])
    assert np.max(np.abs(res.model.weights - truth.weights[:9])) < 1e-9


def test_bounded_lsq_is_the_constrained_optimum():
    rng = np.random.default_rng(1)
    t, u, y = _data('bouc-wen', n=801)
    eps = 1e-9
    for _ in range(4):
        r = np.concatenate([[0.0], np.sort(rng.uniform(1, 70, 9))])
        b = partial_sum_basis(play_operators(u, r)[0])
        yy = y + rng.normal(0, 3e-6, y.size) * (rng.random() < 0.5)
        s = bounded_lsq(b, yy, eps)
        ref = lsq_linear(b, yy, bounds=(eps, np.inf), method='bvls', tol=1e-14).x
        assert np.all(s >= eps)
        cost = np.sum((b @ s - yy) ** 2)
        assert cost <= np.sum((b @ ref - yy) ** 2) * (1 + 1e-9)
        sb, rms = bounded_lsq_batch(b[None], yy, eps)
        np.testing.assert_allclose(sb[0], s, rtol=1e-5, atol=1e-14)
        np.testing.assert_allclose(rms[0], np.sqrt(cost / yy.size), rtol=1e-6)


def test_lsq_enforces_invertibility_when_data_want_otherwise():
    t, u = data.experiment_signal(n_samples=801)
    y = 1e-6 * u - 3e-6 * np.maximum(u - 40.0, 0.0)   # falling above 40 V
    res = identify(t, u, y, 'lsq')
    s = np.cumsum(res.model.weights)
    assert np.all(s >= 1e-9 * (1 - 1e-9))
    assert np.min(s) < 1e-8   # the bound is active


@pytest.mark.parametrize('kind', ['dense-pi', 'bouc-wen'])
def test_pso_reaches_lsq_within_2_percent(rich, kind):
    t, u, y, ref = rich[kind]
    ratios = [identify(t, u, y, 'pso', seed=s).rms_error_m / ref.rms_error_m
              for s in range(10)]
    assert min(ratios) >= 1 - 1e-9     # lsq is the optimum
    assert sum(r <= 1.02 for r in ratios) >= 9


def test_pso_is_deterministic_and_reports_history(rich):
    t, u, y, _ = rich['bouc-wen']
    a = identify(t, u, y, 'pso', seed=5)
    b = identify(t, u, y, 'pso', seed=5)
    c = identify(t, u, y, 'pso', seed=6)
    np.testing.assert_array_equal(a.model.weights, b.model.weights)
    assert not np.array_equal(a.model.weights, c.model.weights)
    assert a.history.size == 151 and np.all(np.diff(a.history) <= 0)
    assert 0 <= a.converged_generation <= 150
    assert a.history[a.converged_generation] <= a.history[-1] * (1 + 1e-3)


@pytest.mark.parametrize('kind', ['dense-pi', 'bouc-wen'])
def test_pso_thresholds_beats_lsq_with_paper_thresholds(rich, kind):
    t, u, y, ref = rich[kind]
    np.testing.assert_allclose(ref.model.thresholds, paper_thresholds(u, 10))
    small = {'pso_thresholds': {'population': 8, 'generations': 15}}
    res = identify(t, u, y, 'pso-thresholds', seed=0, params=small)
    assert res.rms_error_m < 0.9 * ref.rms_error_m
    assert np.all(np.diff(res.model.thresholds) > 0)
    assert np.all(np.cumsum(res.model.weights) > 0)


def test_report_has_error_against_voltage(rich):
    t, u, y, ref = rich['bouc-wen']
    d = json.loads(ref.to_json())
    for key in ('rms_error_m', 'max_error_m', 'thresholds_v', 'weights', 'method',
                'seconds', 'error_vs_voltage'):
        assert key in d
    bins = d['error_vs_voltage']
    assert sum(b['samples'] for b in bins) == u.size
    assert max(b['max_abs_error_m'] for b in bins) == pytest.approx(d['max_error_m'])


def _bad(case):
    t, u, y = _data('bouc-wen', n=201)
    if case == 'nan':
        y = y.copy()
        y[17] = np.nan
    elif case == 'inf':
        u = u.copy()
        u[3] = np.inf
    elif case == 'lengths':
        y = y[:-1]
    elif case == 'time':
        t = t.copy()
        t[50] = t[49]
    elif case == 'few':
        t, u, y = t[:5], u[:5], y[:5]
    elif case == 'constant':
        u = np.full_like(u, 30.0)
    return t, u, y


@pytest.mark.parametrize('case,msg', [
    ('nan', 'displacement_m has 1 non-finite value.*sample 17'),
    ('inf', 'voltage_v has 1 non-finite'),
    ('lengths', 'unequal lengths'),
    ('time', 'not strictly increasing at sample 50'),
    ('few', '5 samples are fewer than the 10 operators'),
    ('constant', 'voltage is constant'),
])
def test_bad_data_gives_clear_errors(case, msg):
    with pytest.raises(ValueError, match=msg):
        identify(*_bad(case), 'lsq')


def test_voltage_range_leaving_operators_idle():
    t, u, y = _bad('ok')
    with pytest.raises(ValueError, match='operator 9 .*never active'):
        identify(t, 0.5 * u, y, 'lsq', thresholds=np.arange(10) * 5.0)


@pytest.mark.ros  # starts a process
def test_cli_identify_writes_model_and_json(tmp_path, capsys):
    t, u, y = _data('dense-pi', n=801)
    csv = tmp_path / 'd.csv'
    data.save_csv(csv, t, u, y)
    out = tmp_path / 'm.yaml'
    png = tmp_path / 'fit.png'
    assert cli_main(['identify', str(csv), '--out', str(out), '--json',
                     '--plot', str(png)]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep['method'] == 'lsq' and rep['rms_error_m'] < 1e-7
    m = __import__('fiber_align.hysteresis.pi', fromlist=['PIModel']).PIModel.load(out)
    np.testing.assert_allclose(m.weights, rep['weights'])
    assert png.stat().st_size > 1000


def test_cli_bad_data_exits_2_without_writing(tmp_path, capsys):
    t, u, y = _bad('nan')
    csv = tmp_path / 'd.csv'
    data.save_csv(csv, t, u, y)
    out = tmp_path / 'm.yaml'
    assert cli_main(['identify', str(csv), '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'non-finite' in err and 'Traceback' not in err
    assert not out.exists()
    assert cli_main(['identify', str(tmp_path / 'missing.csv'), '--out', str(out)]) == 2
    assert 'does not exist' in capsys.readouterr().err
