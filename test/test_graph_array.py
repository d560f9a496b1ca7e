# SPDX-License-Identifier: Apache-2.0
"""
The fiber array on the graph: its description (pure) and ``bringup --array``.

``bringup --array --sync lockstep`` starts the array of ``graph/array.py`` (three
actuator graphs in one ``control_graph`` process, the array's optics, the array
sequencer), aligns and writes every sample's three displacements, three setpoints and the
two outer channels' readings; the offline ``array`` bench
(:mod:`fiber_align.simulation.array_scenarios`) with ``align`` before the same sample must
give the same numbers, to the last bit.
"""

import json
import sys

import numpy as np
import pytest

from fiber_align.analysis.cli import analyze_bag
from fiber_align.graph import array as ga
from fiber_align.graph.arguments import describe
from fiber_align.graph.params import GraphError
from fiber_align.plant import array_optics as ao
from fiber_align.simulation import array_scenarios as sc
from fiber_align.simulation import harness as hs
from procs import run_bounded
from test_graph_description import CONTROL, setup_py_nodes


def test_composed_array_is_one_process_hosting_three_axes_the_optics_and_the_sequencer():
    g = ga.build_array()
    assert [(p.name, p.executable, p.namespace) for p in g.processes] == [
        ('array', 'control_graph', 'array'), ('lifecycle_manager', 'lifecycle_manager', 'array')]
    assert g.processes[0].nodes == tuple('%s/%s' % (a, n) for a in ('x', 'y_left', 'y_right')
                                         for n in CONTROL) + ('simulated_array_optics',
                                                              'array_sequencer')
    assert g.node_params('lifecycle_manager')['node_names'] == [
        '%s/actuator_driver' % a for a in ga.AXES]
    assert g.node_params(ga.SEQUENCER)['machine'] == 'array'
    assert g.node_params(ga.OPTICS)['link'] == 'array'
    assert {p.executable for p in ga.build_array(composed=False).processes} <= set(
        setup_py_nodes())


@pytest.mark.parametrize('seed', [0, 2])
def test_array_takes_seeds_chip_and_layout_from_the_offline_description(seed):
    g = ga.build_array(seed=seed, sync_mode='lockstep')
    plant = sc.run_seeds(seed)['plant']
    assert [g.node_params('%s/simulated_actuator' % a)['seed'] for a in ga.AXES] == [
        plant, plant + 1, plant + 2]
    optics = g.node_params(ga.OPTICS)
    assert optics['seed'] == sc.run_seeds(seed)['detector'] and optics['layout_seed'] == seed
    assert tuple(optics[k] for k in ga.CHIP_KEYS) == sc.random_chip(seed)


def test_launch_argument_array_chooses_it_and_refuses_the_others():
    g = describe({'array': 'true', 'seed': '3'})
    assert g.namespace == 'array' and g.scenario == 'array' and g.seed == 3
    with pytest.raises(GraphError, match='rig:=true: not available with array:=true'):
        describe({'array': 'true', 'rig': 'true'})
    with pytest.raises(GraphError, match='scenario'):
        describe({'array': 'true', 'scenario': 'step'})


@pytest.mark.ros  # starts the array's processes
def test_array_lockstep_equals_the_offline_run(tmp_path):
    trace, summary = tmp_path / 'array.csv', tmp_path / 'array.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--array',
                             '--sync', 'lockstep', '--seed', '5', '--trace', str(trace),
                             '--summary', str(summary), '--quiet',
                             '--record', str(tmp_path / 'bag')], 120)
    assert code == 0, out
    s = json.loads(summary.read_text(encoding='utf-8'))
    cols = np.loadtxt(trace, delimiter=',', skiprows=1, ndmin=2)
    head = trace.read_text(encoding='utf-8').split('\n', 1)[0].split(',')
    graph = {h.rsplit('_', 1)[0] if h not in ('k', 't_s') else h: c
             for h, c in zip(head, cols.T)}
    bench = sc.build(5, record=True)
    res = hs.align_bench(bench, idle_s=s['align_sample'] * bench.period_s)
    off = bench.trace()
    n = off['t'].size
    assert res['state'] == 'TRACKING' and s['state'] == 'TRACKING'
    assert graph['k'].size >= n, 'the graph ran past the offline run'
    for k in sc.ArrayBench.MEASURED + sc.ArrayBench.SETPOINT:
        assert np.max(np.abs(graph[k][:n] - off[k])) <= 1e-15, k     # m
    for k in sc.ArrayBench.POWERS:
        assert np.max(np.abs(graph[k][:n] / off[k] - 1.0)) <= 1e-12, k   # W, relative
    assert s['time_to_peak_s'] == pytest.approx(res['time_to_peak_s'], abs=1e-12)
    assert s['peak_samples'] == res['peak_samples']
    assert s['offline']['equal'] and s['offline']['samples'] == n
    # the recorded model (array_model): the report's array section
    res, _ = analyze_bag(tmp_path / 'bag')
    a, c = res['metrics']['array'], bench.link.coupling
    assert a['channels'] == c.n and a['measured'] == [1, c.n]
    assert [a['best_pose'][k] for k in ao.POSE_LABELS] == pytest.approx(c.best(), abs=1e-12)
    assert a['worst_channel_loss_db'] <= 0.1            # the goal, at the run's end
    assert a['time_to_aligned_s'] == pytest.approx(s['time_to_peak_s'], abs=1e-9)
    assert a['samples'] == s['peak_samples']
    # its pose: the plants' true one at its sample, the sensors' within 5 sigma (10 nm)
    k = int(round(a['t_s'] / bench.period_s))
    seen = ao.pose([graph[m][k] for m in sc.ArrayBench.MEASURED], c.roll_arm_m)
    assert k > s['align_sample'] and abs(a['t_s'] - k * bench.period_s) < 1e-9
    tol = (5e-8, 5e-8, 5e-8 * 2 ** 0.5 / c.roll_arm_m)         # m, m, rad
    for p, v, t in zip(ao.POSE_LABELS, seen, tol):
        assert abs(a['pose'][p] - v) <= t, (p, a['pose'][p], v)
