# SPDX-License-Identifier: Apache-2.0
"""Closed-loop tests: the issue's targets (short runs to stay fast)."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from fiber_align.simulation import simulate

# The configuration, loaded once and passed down, as a program does (the fuzzy surface in
# it takes ~0.1 s to build).
SETUP = simulate.load_setup()


def run(*args, **kw):
    """Return :func:`fiber_align.simulation.simulate.run` with the loaded configuration."""
    return simulate.run(*args, setup=SETUP, **kw)


@pytest.mark.parametrize('rate', [1000.0, 10000.0])
def test_fuzzy_step_linear_plant(rate):
    """Fuzzy PID on the plant without hysteresis: settling <= 15 ms, overshoot <= 5 %."""
    m = run('step', 'fuzzy', rate_hz=rate, plant='linear').metrics
    assert m['settling_time_s'] <= 0.015 and m['overshoot_pct'] <= 5.0


@pytest.mark.parametrize('rate,limit', [(10000.0, 0.003), (1000.0, 0.008)])
def test_composite_step_default_plant(rate, limit):
    """Composite with shaping settles within 3 ms at 10 kHz and 8 ms at 1 kHz, <= 2 %."""
    m = run('step', 'composite', rate_hz=rate).metrics
    assert m['settling_time_s'] <= limit and m['overshoot_pct'] <= 2.0


@pytest.mark.parametrize('scenario,limit', [('sine', 0.2e-6), ('triangle', 0.08e-6)])
def test_tracking_identified_model(scenario, limit):
    """Composite tracking at 10 kHz with the identified feedforward model (3 s runs)."""
    m = run(scenario, 'composite', rate_hz=10000.0, duration_s=2.5).metrics
    assert m['max_error_m'] <= limit


def test_tracking_with_noise_within_twice_sensor_noise():
    """Noise on: tracking RMS error within 2 x the 10 nm sensor noise."""
    m = run('sine', 'composite', rate_hz=10000.0, duration_s=2.0, noise=True).metrics
    assert m['rms_error_m'] <= 20e-9


def test_deterministic_for_a_seed():
    """Two runs with the same seed and noise give identical arrays."""
    a = run('step', 'fuzzy', rate_hz=1000.0, duration_s=0.02, noise=True, seed=5)
    b = run('step', 'fuzzy', rate_hz=1000.0, duration_s=0.02, noise=True, seed=5)
    assert (a.y_meas == b.y_meas).all() and (a.v == b.v).all()


def test_nan_measurement_holds_and_is_flagged():
    """A NaN measurement holds the controller output and is counted in the metrics."""
    from fiber_align.simulation.simulate import make_plant
    p = make_plant('default', 1000.0)
    p.nan_samples = frozenset([10, 11])
    res = run('step', 'fuzzy', rate_hz=1000.0, duration_s=0.03, plant_obj=p)
    assert res.metrics['measurement_held_samples'] == 2
    assert res.fb[10] == res.fb[9] and res.fb[11] == res.fb[9]
    assert math.isfinite(res.metrics['settling_time_s'])


def test_unreachable_reference_is_clamped_and_reported():
    """A 200 um step is clamped to the reachable range and counted."""
    res = run('step', 'composite', rate_hz=1000.0, duration_s=0.02, reference_scale=2.5)
    assert res.metrics['reference_clamped_samples'] == res.t.size
    assert res.r.max() == pytest.approx(res.metrics['reachable_m'])


@pytest.mark.ros  # starts a process
def test_cli_json_and_error():
    """The CLI prints the required JSON keys; a bad name exits 2 with one line."""
    exe = [sys.executable, '-c', 'import sys; from fiber_align.cli import main; '
           'sys.exit(main())']
    out = subprocess.run(exe + ['simulate', '--scenario', 'step', '--controller', 'pid',
                                '--rate', '1000', '--duration', '0.02', '--json'],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    m = json.loads(out.stdout)
    for k in ('settling_time_s', 'overshoot_pct', 'rise_time_s', 'rms_error_m',
              'max_error_m', 'max_voltage_v'):
        assert k in m
    bad = subprocess.run(exe + ['simulate', '--controller', 'nope'], capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize('rate,limit', [(10000.0, 0.003), (1000.0, 0.008)])
def test_steps_from_non_rest_hysteresis_states(rate, limit):
    """
    Every step from a non-rest hysteresis state settles without big overshoot.

    The staircase steps by 5-62 um, up and down, each from the state the previous moves
    left (e.g. a mid-range 20 -> 60 um); each settles within the issue-4 time, with
    overshoot <= 2 % for steps of 10 um or more and <= 0.15 um for any.
    """
    m = run('staircase', 'composite', rate_hz=rate).metrics
    steps = m['steps']
    assert len(steps) == 12
    assert any(s['from_m'] == 20e-6 and s['to_m'] == 60e-6 for s in steps)
    for s in steps:
        size = abs(s['to_m'] - s['from_m'])
        assert s['settling_time_s'] <= limit, s
        assert s['overshoot_pct'] / 100.0 * size <= 0.15e-6, s
        if size >= 10e-6:
            assert s['overshoot_pct'] <= 2.0, s


def test_switch_on_step_at_1khz_does_not_ring():
    """The sequencer's 45 um switch-on after earlier moves lands without ringing."""
    from fiber_align.simulation.alignment_bench import CompositeLoop
    loop = CompositeLoop(period_s=1e-3, noise=False)
    for target, n in ((45e-6, 30), (0.0, 30)):
        for _ in range(n):
            loop.step(target)
    xs = []
    for _ in range(20):
        loop.step(45e-6)
        xs.append(loop.position_m)
    assert max(xs) <= 45e-6 * 1.02
    assert all(abs(x - 45e-6) <= 0.9e-6 for x in xs[2:])   # within 2 % from 3 ms on


def test_paper_plant_composite_step():
    """On the paper's Table 3 plant the composite settles within 8 ms at 1 kHz."""
    m = run('step', 'composite', rate_hz=1000.0, plant='paper').metrics
    assert m['settling_time_s'] <= 0.008 and m['overshoot_pct'] <= 2.0


def test_metrics_are_analyze_loop_metrics_of_the_measured_signal():
    """The simulate metrics are loop_metrics of the measured displacement; true_* kept."""
    from fiber_align.simulation.metrics import loop_metrics
    res = run('step', 'fuzzy', rate_hz=1000.0, duration_s=0.03, noise=True, seed=3)
    m = res.metrics
    lm = loop_metrics(res.t, res.r, res.y_meas, res.v, (-20.0, 100.0),
                      skip_s=m['tracking_skip_s'])
    assert m['tracking_skip_s'] == pytest.approx(0.5 * res.t[-1])
    assert m['settling_time_s'] == lm['steps'][0]['settling_time_s']
    assert m['overshoot_pct'] == lm['steps'][0]['overshoot_pct']
    assert m['rms_error_m'] == lm['tracking']['rms_error_m']
    assert m['max_voltage_v'] == lm['saturation']['v_max_seen_v']
    tm = loop_metrics(res.t, res.r, res.y_true, skip_s=m['tracking_skip_s'])
    assert m['true_rms_error_m'] == tm['tracking']['rms_error_m']
    assert m['true_rms_error_m'] != m['rms_error_m']      # noise is on: they differ


def test_default_model_is_the_compensator_file():
    """The offline default feedforward model is the generated model file (as on the graph)."""
    from fiber_align.config import config_path
    from fiber_align.simulation import simulate
    from fiber_align.hysteresis.pi import PIModel
    setup = simulate.load_setup()
    model = simulate.default_model('default', setup)
    ref = PIModel.load(str(config_path(simulate.MODEL_FILE)))
    assert np.array_equal(model.thresholds, ref.thresholds)
    assert np.array_equal(model.weights, ref.weights)
    a = run('step', 'composite', rate_hz=1000.0, duration_s=0.01)
    b = run('step', 'composite', rate_hz=1000.0, duration_s=0.01, model=ref)
    assert np.array_equal(a.ff, b.ff)
    c = run('step', 'composite', rate_hz=1000.0, duration_s=0.01,
            model=str(config_path('hysteresis_paper.yaml')))
    assert not np.array_equal(a.ff, c.ff)                 # --model still overrides
    # on another plant the model is identified on that plant
    assert not np.array_equal(simulate.default_model('paper', setup).weights, ref.weights)


def test_compensator_model_file_is_the_regenerated_identification(tmp_path):
    """
    `tuning --compensator` writes the model as a file of its own; the committed one is it.

    The hand-edited compensator.yaml is not touched. The least-squares solve differs in
    the last bits between BLAS builds, so the committed weights are compared to a
    relative 1e-9 (measured here: 3.3e-11 at most), the file written here
    exactly.
    """
    from fiber_align.config import config_path, load_params
    from fiber_align.hysteresis.pi import PIModel
    from fiber_align.simulation import simulate, tuning
    settings = config_path('compensator.yaml')
    before = settings.read_bytes()
    dst = tmp_path / 'compensator_model.yaml'
    assert tuning.main(['--compensator', '--output', str(dst)]) == 0
    assert settings.read_bytes() == before
    written = load_params(str(dst), simulate.COMPENSATOR_NODE)
    assert written['model_plant'] == 'default'
    assert written['model_source'].startswith('lsq 20 operators, 0.1 Hz 0-100 V triangle')
    model = simulate.compensator_identified_model('default', simulate.load_setup())
    back = PIModel.load(str(dst))
    assert np.array_equal(back.thresholds, model.thresholds)
    assert np.array_equal(back.weights, model.weights)
    committed = PIModel.load(str(config_path(simulate.MODEL_FILE)))
    assert np.array_equal(committed.thresholds, model.thresholds)
    np.testing.assert_allclose(committed.weights, model.weights, rtol=1e-9, atol=0.0)


def test_cli_alignment_scenarios_pass_options(capsys):
    """The simulate --scenario switch dispatches with --loop, --cycles, --slot (SI)."""
    from fiber_align.cli import main
    code = main(['simulate', '--scenario', 'switch', '--loop', 'ideal', '--cycles', '2',
                 '--slot', '30e-6', '--json'])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out['cycles'] == 2 and out['loop'] == 'ideal'
    assert out['slot_m'] == pytest.approx(30e-6)
    assert main(['simulate', '--scenario', 'step', '--slot', '30e-6']) == 2
    assert main(['simulate', '--scenario', 'track', '--drift', '5']) == 2
