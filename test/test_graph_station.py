# SPDX-License-Identifier: Apache-2.0
"""
The coupled station on the graph: its description (pure) and ``bringup --station``.

``bringup --station --sync lockstep`` starts the station of ``graph/station.py`` (four
actuator graphs in one ``control_graph`` process, the chip's optics, the station
sequencer), aligns and writes every sample's four displacements, four setpoints and the
power; the offline station bench (:mod:`fiber_align.simulation.station_scenarios`) with
``align`` before the same sample must give the same numbers, to the last bit (the graph
computes the same float64 operations in the same order; the bounds leave room for one
rounding step only).
"""

import json
import sys

import numpy as np
import pytest

from fiber_align.graph import station as gs
from fiber_align.graph.params import GraphError
from fiber_align.simulation import station_scenarios as sc
from procs import run_bounded
from test_graph_description import CONTROL, setup_py_nodes


def test_composed_station_is_one_process_hosting_four_axes_the_optics_and_the_sequencer():
    g = gs.build_station()
    assert [(p.name, p.executable, p.namespace) for p in g.processes] == [
        ('station', 'control_graph', 'station'),
        ('lifecycle_manager', 'lifecycle_manager', 'station')]
    st = g.processes[0]
    assert st.nodes == tuple('%s/%s' % (a, n) for a in gs.AXES for n in CONTROL) + (
        'simulated_station_optics', 'station_sequencer')
    assert st.hosted('station')[0] == ('simulated_actuator', '/station/in/x')
    assert st.hosted('station')[-1] == ('station_sequencer', '/station')
    assert g.node_params('lifecycle_manager')['node_names'] == [
        '%s/actuator_driver' % a for a in gs.AXES]
    assert {p.executable for p in gs.build_station(composed=False).processes} <= set(
        setup_py_nodes())


@pytest.mark.parametrize('seed', [0, 2])
def test_station_takes_seeds_and_facets_from_the_offline_description(seed):
    g = gs.build_station(seed=seed, sync_mode='lockstep')
    plant = sc.run_seeds(seed)['plant']
    assert [g.node_params('%s/simulated_actuator' % a)['seed'] for a in gs.AXES] == [
        plant, plant + 1, plant + 2, plant + 3]
    assert [g.node_params('%s/simulated_actuator' % a)['publish_clock']
            for a in gs.AXES] == [True, False, False, False]
    optics = g.node_params(gs.OPTICS)
    assert optics['seed'] == sc.run_seeds(seed)['detector']
    assert tuple(optics[k] for k in gs.FACET_KEYS) == sc.random_facets(seed)
    assert g.sync_mode == 'lockstep' and g.node_params(gs.SEQUENCER)['sync_mode'] == \
        'lockstep'


def test_record_hosts_the_recorder_in_the_composed_process_else_the_clock_waits(tmp_path):
    g = gs.build_station(record=str(tmp_path / 'bag'), namespace='bench2')
    station = g.processes[0]
    assert [p.executable for p in g.processes] == ['control_graph', 'lifecycle_manager']
    assert ('bag_recorder', '/bench2') in station.hosted()
    assert station.arguments[1].split(',')[-1] == 'bag_recorder'   # built last
    # what it reads from the bus: every axis's recorded topics and the power
    local = set(station.local_topics())
    assert {'/bench2/%s/%s' % (a, t) for a in gs.AXES for t in gs.PER_AXIS_RECORDED} \
        <= local and '/bench2/optical_power' in local
    rec = g.node_params('bag_recorder')
    assert rec['output'] == str(tmp_path / 'bag')
    assert 'out/y/reference' in rec['topics'] and 'optical_power' in rec['topics']
    assert not g.node_params('in/y/simulated_actuator').get('start_after_reader')
    g = gs.build_station(record=str(tmp_path / 'bag'), namespace='bench2', composed=False)
    assert g.processes[-1].executable == 'bag_recorder'
    assert g.processes[-1].namespace == 'bench2'
    assert g.node_params('in/y/simulated_actuator')['start_after_reader'] == \
        '/bench2/bag_recorder'
    with pytest.raises(GraphError, match='already exists'):
        gs.build_station(record=str(tmp_path))
    with pytest.raises(GraphError, match='seed'):
        gs.build_station(seed=-1)


@pytest.mark.ros  # starts the station's processes
def test_station_lockstep_equals_the_offline_run(tmp_path):
    trace, summary = tmp_path / 'station.csv', tmp_path / 'station.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--station',
                             '--sync', 'lockstep', '--seed', '2', '--trace', str(trace),
                             '--summary', str(summary), '--quiet'], 120)
    assert code == 0, out
    s = json.loads(summary.read_text(encoding='utf-8'))
    cols = np.loadtxt(trace, delimiter=',', skiprows=1, ndmin=2)
    head = trace.read_text(encoding='utf-8').split('\n', 1)[0].split(',')
    graph = {h.rsplit('_', 1)[0] if h not in ('k', 't_s') else h: c
             for h, c in zip(head, cols.T)}
    bench = sc.build(2, record=True)
    res = sc.align_bench(bench, idle_s=s['align_sample'] * bench.period_s)
    off = bench.trace()
    n = off['t'].size
    assert res['state'] == 'TRACKING' and s['state'] == 'TRACKING'
    assert graph['k'].size >= n, 'the graph ran past the offline run'
    for k in sc.StationBench.FIELDS[1:-1]:
        assert np.max(np.abs(graph[k][:n] - off[k])) <= 1e-15, k     # m
    assert np.max(np.abs(graph['p'][:n] / off['p'] - 1.0)) <= 1e-12   # W, relative
    assert s['time_to_peak_s'] == pytest.approx(res['time_to_peak_s'], abs=1e-12)
    assert s['peak_samples'] == res['peak_samples']
    assert s['offline']['equal'] and s['offline']['samples'] == n


@pytest.mark.ros  # starts the station's processes
def test_station_on_a_meter_clamped_at_1_nw_aligns_as_on_a_clean_one(tmp_path):
    """
    Dark is not dead on the station's graph: a meter that reads a constant 1 nW in the dark.

    ``optics.floor_w`` clamps every reading below it (a meter that clamps below its noise
    floor): the first-light search walks the dark on one value again and again. The graph
    ends TRACKING with the motion of the run on a clean meter, sample for sample (only the
    dark readings differ, by at most the floor), so at that run's loss.
    """
    floor_w = 1e-9
    summary = tmp_path / 'station.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--station',
                             '--sync', 'lockstep', '--seed', '2', '-p',
                             '**:optics.floor_w:=%r' % floor_w, '--summary', str(summary),
                             '--quiet'], 120)
    assert code == 0, out
    s = json.loads(summary.read_text(encoding='utf-8'))
    off = s['offline']              # the shipped (clean) meter's run, aligned alike
    assert s['state'] == 'TRACKING' and off['state'] == 'TRACKING', s
    assert 'stuck' not in out and 'frozen' not in out
    assert off['samples'] == off['offline_samples'], off
    moves = {k: v for k, v in off.items() if k.startswith('max_abs_') and k != 'max_abs_p'}
    assert moves and max(moves.values()) <= 1e-15, moves                    # m
    assert 0.0 < off['max_abs_p'] <= floor_w, off['max_abs_p']              # W: the dark only
    assert off['final_loss_db'] < 0.1, off['final_loss_db']


@pytest.mark.ros  # starts the station's processes
@pytest.mark.slow
def test_a_driver_disabled_mid_align_holds_the_station_which_resumes_after_the_re_arm():
    """Realtime: ``out/x`` disabled while SEARCHING; HELD names it; enabled: TRACKING."""
    import time

    from std_srvs.srv import SetBool, Trigger

    from fiber_align.graph.params import PLANT
    from fiber_align.bringup.harness import Harness
    g = gs.build_station(seed=2, sync_mode='realtime', overrides={PLANT: {'autostart': False}})
    facets = np.array([g.node_params(gs.OPTICS)[k] for k in gs.FACET_KEYS])
    h = Harness(g, dict(streams={}))

    def wait(cond, what, timeout_s=20.0):
        h.obs.wait(cond, timeout_s, h.alive, what)

    def enable(on):
        res = h.obs.call(h.obs.client(SetBool, 'out/x/actuator_driver/enable'),
                         SetBool.Request(data=on), 10.0, h.alive)
        assert res.success, res.message

    def seen(state, since):
        with h.obs.lock:
            return [st for _, st in h.obs.states[since:] if st['state'] == state]
    try:
        h.start()
        h.obs.start()
        h.run(True)
        time.sleep(0.3)
        wait(lambda: h.obs.status.get('state') == 'IDLE', 'IDLE')
        res = h.obs.call(h.obs.client(Trigger, 'align'), Trigger.Request(), 10.0, h.alive)
        assert res.success, res.message
        wait(lambda: h.obs.status.get('state') == 'SEARCHING', 'SEARCHING')
        n = len(h.obs.states)
        enable(False)
        wait(lambda: seen('HELD', n), 'HELD')
        held = seen('HELD', n)[0]
        assert 'x_out' in held['hold_reason'] and 'during SEARCHING' in held['hold_reason']
        refused = h.obs.call(h.obs.client(Trigger, 'align'), Trigger.Request(), 10.0, h.alive)
        assert not refused.success and 'out/x/actuator_driver' in refused.message
        time.sleep(0.2)
        assert h.obs.status.get('state') == 'HELD'
        enable(True)
        wait(lambda: h.obs.status.get('state') in ('TRACKING', 'FAULT'), 'TRACKING', 30.0)
        st = h.obs.status
        with h.obs.lock:
            after = [s['state'] for _, s in h.obs.states[n:]]
        print(after, held['hold_reason'])
        assert st['state'] == 'TRACKING', st
        assert not seen('FAULT', n) and after[-2:] == ['PEAKING', 'TRACKING'], after
        # the joint peak found after the re-arm: the aligned point at the facets
        assert np.max(np.abs(np.asarray(st['aligned_m']) - facets)) < 0.5e-6, st
    finally:
        h.stop()
        h.close()


@pytest.mark.ros  # starts the station's processes
@pytest.mark.slow
def test_a_meter_frozen_mid_tracking_is_named_within_1_s_on_the_realtime_station():
    """
    Issue 39.3 on the station's graph: its meter freezes while TRACKING.

    The optics node's fault injection ``meter_frozen`` is set live, as ``ros2 param set``
    does: the sequencer faults or holds, naming the frozen meter, within 1 s of the
    parameter's answer.
    """
    import time

    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from std_srvs.srv import Trigger

    from fiber_align.bringup.harness import Harness
    h = Harness(gs.build_station(seed=2, sync_mode='realtime'), dict(streams={}))

    def state():
        return h.obs.status.get('state')
    try:
        h.start()
        h.obs.start()
        h.run(True)
        h.obs.wait(lambda: state() == 'IDLE', 20.0, h.alive, 'IDLE')
        res = h.obs.call(h.obs.client(Trigger, 'align'), Trigger.Request(), 10.0, h.alive)
        assert res.success, res.message
        h.obs.wait(lambda: state() in ('TRACKING', 'FAULT'), 30.0, h.alive, 'TRACKING')
        assert state() == 'TRACKING', h.obs.status
        time.sleep(0.5)
        assert state() == 'TRACKING', h.obs.status      # a live meter is never frozen
        req = SetParameters.Request(parameters=[Parameter(
            name='meter_frozen', value=ParameterValue(type=ParameterType.PARAMETER_BOOL,
                                                      bool_value=True))])
        res = h.obs.call(h.obs.client(SetParameters, '%s/set_parameters' % gs.OPTICS), req,
                         10.0, h.alive)
        t0 = time.monotonic()
        assert res.results[0].successful, res.results[0].reason
        h.obs.wait(lambda: state() in ('FAULT', 'HELD'), 3.0, h.alive, 'FAULT or HELD')
        dt = time.monotonic() - t0
        st = h.obs.status
        why = st.get('fault_reason') or st.get('hold_reason')
        print('station: frozen meter named %.3f s after the parameter: %s' % (dt, why))
        assert 'power meter frozen' in why, st
        assert dt < 1.0, (dt, why)
    finally:
        h.stop()
        h.close()
