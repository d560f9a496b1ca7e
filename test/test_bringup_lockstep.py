# SPDX-License-Identifier: Apache-2.0
"""Lockstep graph (real processes, recorded bag) against the offline simulation."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from procs import run_bounded

pytestmark = [pytest.mark.ros, pytest.mark.slow]

STEP_S = 0.05
SINE_S = 0.4


def run_bringup(tmp_path, tag, *args, timeout=120):
    """
    Run ``bringup`` in lockstep; return ``(trace, summary)``.

    ``trace`` is the (t_s, r_m, y_m) array of bringup's ``--trace``; ``summary`` its
    ``--summary`` JSON. Fails on a non-zero exit; on a timeout bringup is interrupted (it stops its
    nodes), then killed.
    """
    trace = tmp_path / ('%s.csv' % tag)
    summary = tmp_path / ('%s.json' % tag)
    cmd = [sys.executable, '-m', 'fiber_align.bringup', '--sync', 'lockstep',
           '--trace', str(trace), '--summary', str(summary), '--quiet'] + list(args)
    code, out = run_bounded(cmd, timeout)
    assert code == 0, out
    return (np.loadtxt(trace, delimiter=',', skiprows=1),
            json.loads(summary.read_text(encoding='utf-8')))


def simulate(scenario, duration, model=None):
    """Return the offline run of the same scenario (composite, 1 kHz, seed 0, noise on)."""
    from fiber_align.simulation import simulate as sim
    return sim.run(scenario, 'composite', rate_hz=1000.0, duration_s=duration, seed=0,
                   noise=True, model=model)


def bag_arrays(bag):
    """Return per-sample arrays of a lockstep bag, read with the analysis bag reader."""
    from fiber_align.analysis import bag as bagio
    from fiber_align.analysis.report import align_to_samples
    streams, lockstep, _ = bagio.read_streams(str(bag), ['displacement', 'setpoint',
                                                         'drive_voltage', 'clock'])
    assert lockstep, 'a lockstep bag holds /clock'
    return align_to_samples(streams, lockstep)


def assert_bag_equals(bag, res):
    """Assert the bag's displacement (and setpoint, drive) equal the offline run's."""
    al = bag_arrays(bag)
    n = res.t.size
    # the scenario answers n samples; the plant measures once more after the last
    # command (the sample no command follows), then the graph holds
    assert al['y'].size == n + 1, 'one displacement per command, plus the last one'
    np.testing.assert_allclose(al['t'][:n], res.t, atol=1e-9)
    assert np.max(np.abs(al['y'][:n] - res.y_meas)) <= 1e-9
    np.testing.assert_allclose(al['setpoint'][:n], res.r, atol=1e-12)
    assert np.isnan(al['setpoint'][n]), 'nothing answers the sample after the run'
    np.testing.assert_allclose(al['drive_voltage'][:n], res.v, atol=1e-9)


@pytest.fixture(scope='module')
def step_runs(tmp_path_factory):
    """
    Run a recorded multi-process lockstep step run; return (folder, its trace and summary).

    Reruns equal it sample for sample: the composed run in a namespace and the run
    restarted after a stalled start below are compared with it exactly.
    """
    tmp = tmp_path_factory.mktemp('step')
    a = run_bringup(tmp, 'a', '--scenario', 'step', '--duration', str(STEP_S),
                    '--record', str(tmp / 'bag_a'), '--multi-process')
    return tmp, a


def test_step_bag_reproduces_simulate(step_runs):
    """The recorded displacement equals `fiber-align simulate` to 1 nm, its metrics too."""
    tmp, (trace_a, sum_a) = step_runs
    res = simulate('step', STEP_S)
    assert_bag_equals(tmp / 'bag_a', res)
    assert np.max(np.abs(trace_a[:, 2] - res.y_meas)) <= 1e-9
    # the run's own metrics are simulate's (same function on the same samples)
    for k in ('settling_time_s', 'overshoot_pct', 'rms_error_m', 'max_error_m'):
        assert sum_a['metrics'][k] == pytest.approx(res.metrics[k], rel=1e-9, abs=1e-15), k
    # every message sent is in the bag
    rec = sum_a['recorded']
    for node, counts in sum_a['sent'].items():
        for topic, n in counts.items():
            if topic == 'setpoint':
                # the recorder records `reference`, what the loop accepted: one each
                assert rec['/reference'] == n, node
                continue
            assert rec['/' + topic.lstrip('/')] == n, (node, topic)


def test_sine_bag_reproduces_simulate(tmp_path):
    """A short sine: the bag's displacement equals the offline loop to 1 nm per sample."""
    run_bringup(tmp_path, 'sine', '--scenario', 'sine', '--duration', str(SINE_S),
                '--record', str(tmp_path / 'bag'))
    assert_bag_equals(tmp_path / 'bag', simulate('sine', SINE_S))


def test_composed_in_a_namespace_equals_multi_process(step_runs, tmp_path):
    """All nodes in one process, in namespace /rig1: the same trace as separate processes."""
    _, (trace_a, _) = step_runs
    trace_c, sum_c = run_bringup(tmp_path, 'composed', '--scenario', 'step', '--duration',
                                 str(STEP_S), '--composed', '--namespace', 'rig1')
    assert sum_c['composed'] and sum_c['namespace'] == 'rig1'
    assert np.array_equal(trace_a, trace_c)


RETRY = """
import sys
from fiber_align import bringup as b
from fiber_align.bringup.observer import Observer, StartStall
start, injected = Observer.start, []


# at the run's start, where the stall check would find the first sample unanswered (a
# check_stall patch raced the graph: a 50-sample lockstep run can end before the first
# check)
def stall_once(self):
    start(self)
    if not injected:
        injected.append(1)
        raise StartStall('injected stall')


Observer.start = stall_once
sys.exit(b.main(sys.argv[1:]))
"""


def test_a_stalled_start_restarts_the_graph_and_gives_the_same_run(step_runs, tmp_path):
    """A first sample left unanswered (a message lost at start-up) restarts the graph."""
    _, (trace_a, _) = step_runs
    trace = tmp_path / 'retry.csv'
    summary = tmp_path / 'retry.json'
    proc = subprocess.Popen([sys.executable, '-c', RETRY, '--scenario', 'step', '--sync',
                             'lockstep', '--duration', str(STEP_S), '--composed', '--trace',
                             str(trace), '--summary', str(summary), '--quiet'],
                            env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    assert proc.returncode == 0, out
    assert 'injected stall; restarting the graph (restart 1, counted in the summary)' in out
    assert json.loads(summary.read_text(encoding='utf-8'))['restarts'] == 1
    assert np.array_equal(np.loadtxt(trace, delimiter=',', skiprows=1), trace_a)
