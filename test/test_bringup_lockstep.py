# SPDX-License-Identifier: Apache-2.0
"""Lockstep graph (real processes) against the offline simulation of the control core."""

import os
import subprocess
import sys

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def run_bringup(tmp_path, scenario, duration, tag):
    """Run ``bringup`` in lockstep; return the trace array (t_s, r_m, y_m)."""
    trace = tmp_path / ('%s_%s.csv' % (scenario, tag))
    cmd = [sys.executable, '-m', 'fiber_align.nodes.bringup', '--scenario', scenario,
           '--sync', 'lockstep', '--duration', str(duration), '--trace', str(trace),
           '--quiet']
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=150)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    assert proc.returncode == 0, out
    return np.loadtxt(trace, delimiter=',', skiprows=1)


@pytest.mark.parametrize('scenario,duration', [('step', 0.05), ('sine', 0.6)])
def test_lockstep_reproduces_simulate(tmp_path, scenario, duration):
    """The graph's displacement equals the offline loop to 1 nm per sample."""
    from fiber_align.config import config_path
    from fiber_align.control import simulate
    from fiber_align.hysteresis.pi import PIModel
    d = run_bringup(tmp_path, scenario, duration, 'a')
    res = simulate.run(scenario, 'composite', rate_hz=1000.0, duration_s=duration, seed=0,
                       noise=True, model=PIModel.load(str(config_path('compensator.yaml'))))
    assert d.shape[0] == res.t.size
    np.testing.assert_allclose(d[:, 0], res.t, atol=1e-9)
    np.testing.assert_allclose(d[:, 1], res.r, atol=1e-12)
    assert np.max(np.abs(d[:, 2] - res.y_meas)) <= 1e-9
    if scenario == 'step':
        d2 = run_bringup(tmp_path, scenario, duration, 'b')
        assert np.array_equal(d, d2), 'two lockstep runs differ'
