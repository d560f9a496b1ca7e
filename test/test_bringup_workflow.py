# SPDX-License-Identifier: Apache-2.0
"""Hysteresis experiment on the graph -> fiber-align identify -> bringup --model."""

import json
import sys

import numpy as np
import pytest

from procs import run_bounded

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: the experiment's full 10 s cycle (0-72-0 V) at 100 Hz: 1000 samples, a few seconds
EXPERIMENT_HZ = 100.0
SINE_S = 0.2


def _run(cmd, timeout=150):
    """Run ``cmd`` bounded by ``timeout`` (s); return ``(returncode, output)``."""
    return run_bounded(cmd, timeout)


def _bringup(*args):
    code, out = _run([sys.executable, '-m', 'fiber_align.bringup', '--sync',
                      'lockstep', '--quiet'] + list(args))
    assert code == 0, out
    return out


def test_experiment_identify_and_model_on_the_graph(tmp_path):
    """The open-loop bag is the offline experiment; its model drives the compensator."""
    from fiber_align.analysis import bag as bagio
    from fiber_align.simulation import simulate
    from fiber_align.hysteresis.pi import PIModel
    exp = tmp_path / 'experiment'
    _bringup('--scenario', 'hysteresis-experiment', '--rate', str(EXPERIMENT_HZ),
             '--record', str(exp))
    t, u, y = bagio.read_hysteresis_experiment(str(exp))
    off = simulate.run('hysteresis-experiment', 'open-loop', rate_hz=EXPERIMENT_HZ,
                       seed=0, noise=True)
    assert t.size == off.t.size == 1000
    assert np.max(np.abs(u - off.v)) <= 1e-9
    assert np.max(np.abs(y - off.y_meas)) <= 1e-9
    assert u.max() == pytest.approx(72.0) and u.min() == pytest.approx(0.0)

    model_file = tmp_path / 'model.yaml'
    code, out = _run([sys.executable, '-m', 'fiber_align.cli', 'identify', str(exp),
                      '--out', str(model_file), '--json'])
    assert code == 0, out
    fit = json.loads(out[out.index('{'):])
    assert fit['rms_error_m'] < 0.5e-6          # 10 operators against the 50 of the truth
    model = PIModel.load(str(model_file))
    assert model.n == 10

    bag = tmp_path / 'sine'
    _bringup('--scenario', 'sine', '--duration', str(SINE_S), '--model', str(model_file),
             '--record', str(bag), '--composed')
    streams, lock, _ = bagio.read_streams(str(bag), ['displacement', 'clock'])
    # one displacement per command, plus the sample after the last command
    y_bag = streams['displacement'].fields['position'][:-1]
    with_model = simulate.run('sine', 'composite', rate_hz=1000.0, duration_s=SINE_S,
                              seed=0, noise=True, model=model)
    default = simulate.run('sine', 'composite', rate_hz=1000.0, duration_s=SINE_S, seed=0,
                           noise=True)
    assert np.max(np.abs(y_bag - with_model.y_meas)) <= 1e-9
    assert np.max(np.abs(y_bag - default.y_meas)) > 1e-8, 'the --model file was not used'
