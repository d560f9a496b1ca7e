# SPDX-License-Identifier: Apache-2.0
"""
The two-axis rig on the ROS graph (``bringup --rig``) against the offline ``align2d``.

``bringup --rig --sync lockstep`` starts the rig of ``graph/rig.py`` (two actuator graphs
``/rig/x``, ``/rig/y``, the optics and the 2-D sequencer), aligns and writes every sample's
displacements, power and setpoints; the offline bench of
:mod:`fiber_align.simulation.alignment2d_scenarios`, with ``align`` before the same sample,
must give the same numbers. The graph computes the same float64 operations on the same
inputs in the same order (messages carry float64; the nodes' times are ``k T`` as offline),
so the runs agree to the last bit: the bounds leave room for one rounding step only.
"""

import json
import sys

import numpy as np
import pytest

from fiber_align.simulation import alignment2d_scenarios as a2
from procs import run_bounded

pytestmark = [pytest.mark.ros]


def run_rig(tmp_path, seed, *args, timeout=90):
    """Run ``bringup --rig`` in lockstep; return ``(trace columns, summary)``."""
    trace, summary = tmp_path / 'rig.csv', tmp_path / 'rig.json'
    cmd = [sys.executable, '-m', 'fiber_align.bringup', '--rig', '--sync', 'lockstep',
           '--seed', str(seed), '--trace', str(trace), '--summary', str(summary),
           '--quiet'] + list(args)
    code, out = run_bounded(cmd, timeout)
    assert code == 0, out
    cols = np.loadtxt(trace, delimiter=',', skiprows=1, ndmin=2)
    names = ('k', 't', 'mx', 'my', 'p', 'rx', 'ry')
    return dict(zip(names, cols.T)), json.loads(summary.read_text(encoding='utf-8'))


def assert_equals_offline(graph, summary, seed):
    """Every sample of the graph equals the offline run with the same align sample."""
    bench = a2.build(seed=seed, record=True)
    res = a2.align_bench(bench, idle_s=summary['align_sample'] * bench.period_s)
    off = bench.trace()
    n = off['t'].size
    assert res['state'] == 'TRACKING' and summary['state'] == 'TRACKING'
    assert graph['k'].size >= n, 'the graph ran past the offline run'
    for k in ('mx', 'my', 'rx', 'ry'):
        assert np.max(np.abs(graph[k][:n] - off[k])) <= 1e-15, k     # m
    assert np.max(np.abs(graph['p'][:n] / off['p'] - 1.0)) <= 1e-12  # W, relative
    assert summary['time_to_peak_s'] == pytest.approx(res['time_to_peak_s'], abs=1e-12)
    assert summary['peak_samples'] == res['peak_samples']
    assert summary['offline']['equal'] and summary['offline']['samples'] == n


def test_rig_align2d_composed_equals_offline(tmp_path):
    """Composed (one control_graph process for the rig): seed 0, the docs' example run."""
    graph, summary = run_rig(tmp_path, 0)
    assert summary['composed'] and summary['namespace'] == 'rig'
    assert_equals_offline(graph, summary, 0)


def test_rig_align2d_multi_process_equals_offline(tmp_path):
    """One process per node (eleven processes), another seed and target."""
    graph, summary = run_rig(tmp_path, 3, '--multi-process')
    assert not summary['composed']
    assert_equals_offline(graph, summary, 3)
