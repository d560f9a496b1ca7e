# SPDX-License-Identifier: Apache-2.0
"""Tests of the simulated actuator."""

import math

import numpy as np
import pytest

from fiber_align.config import config_path, ConfigError, load_params
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics
from fiber_align.hysteresis.truth import Linear
from fiber_align.plant.actuator import SimulatedActuator


def _lin(rate=10000.0, **kw):
    """Return a linear-law plant."""
    wn, alpha = design_dynamics(load_actuator())
    return SimulatedActuator(1.0 / rate, Linear(alpha), wn, 0.03, v_min=-20, v_max=100,
                             **kw), wn, alpha


def test_exact_discretisation_matches_analytic_step():
    """A held step follows the analytic underdamped response at every sample."""
    p, wn, alpha = _lin()
    p.reset()
    z = 0.03
    wd = wn * math.sqrt(1 - z * z)
    for k in range(1, 200):
        p.step(10.0)
        t = k * 1e-4
        ref = alpha * 10 * (1 - math.exp(-z * wn * t) * (math.cos(wd * t)
                                                         + z * wn / wd * math.sin(wd * t)))
        assert p.position_m == pytest.approx(ref, abs=1e-12)


def test_amplifier_clamp_and_slew():
    """The amplifier clamps to [v_min, v_max] and limits the change per period."""
    p, _, _ = _lin(rate=1000.0, slew_rate_v_per_s=1e4)
    p.reset()
    p.step(500.0)
    assert p.v_applied == 10.0
    for _ in range(20):
        p.step(500.0)
    assert p.v_applied == 100.0
    p.step(math.nan)
    assert p.v_applied == 100.0


def test_noise_is_seeded_and_rms_right():
    """Same seed, same noise; the RMS equals the configured value."""
    a, _, _ = _lin(noise_rms_m=10e-9, seed=3)
    b, _, _ = _lin(noise_rms_m=10e-9, seed=3)
    ya = [a.step(0.0) for _ in range(5000)]
    yb = [b.step(0.0) for _ in range(5000)]
    assert ya == yb
    assert np.std(ya) == pytest.approx(10e-9, rel=0.05)
    a.reset()
    assert [a.step(0.0) for _ in range(5)] == ya[:5]


def test_config_plant_defaults_reach_82_um():
    """The default plant (dense-pi truth) reaches 82 um inside its amplifier range."""
    p = SimulatedActuator.from_config()
    assert p.reachable_m() > 82e-6
    assert p.v_max == 100.0


def test_broken_or_missing_config_is_one_clear_error(tmp_path):
    """No silent default resonance: a bad actuator or plant config names file and key."""
    good = (config_path('actuator.yaml')).read_text(encoding='utf-8')
    bad = tmp_path / 'actuator.yaml'
    bad.write_text(good.replace('youngs_modulus', 'youngs_modulus_typo', 1)
                   if 'youngs_modulus' in good else good + '    surprise_key: 1.0\n',
                   encoding='utf-8')
    with pytest.raises(ConfigError, match='actuator.yaml'):
        load_actuator(str(bad))
    with pytest.raises(ConfigError, match='missing'):
        load_actuator(str(tmp_path / 'missing.yaml'))
    params = load_params('plant.yaml', 'simulated_actuator')
    del params['damping_ratio']
    with pytest.raises(ConfigError, match='plant.yaml.*damping_ratio'):
        SimulatedActuator.from_params(params)
