# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.graph.arguments`: one step from launch arguments to a graph."""

import pytest

from fiber_align.bringup.cli import graph as bringup_graph, parse_args
from fiber_align.graph.arguments import ARGUMENTS, describe, describe_run, MACHINES
from fiber_align.graph.description import Graph
from fiber_align.graph.params import GraphError, PLANT
from fiber_align.graph.rig import RigGraph

DEFAULTS = {name: default for name, default, *_ in ARGUMENTS}


def launch(**given):
    """Return the graph ``ros2 launch`` starts for ``given`` (strings, as launch has them)."""
    return describe(dict(DEFAULTS, **given))


@pytest.mark.parametrize('given, kind, namespace, scenario', [
    ({}, Graph, '', 'none'),
    ({'rig': 'true'}, RigGraph, 'rig', 'align2d'),
    ({'station': 'true'}, RigGraph, 'station', 'station'),
    ({'hardware': 'true'}, Graph, '', 'align'),
    ({'rig': 'true', 'hardware': 'true'}, RigGraph, 'rig', 'align2d'),
    ({'rig': 'true', 'namespace': 'left'}, RigGraph, 'left', 'align2d'),
])
def test_the_switches_choose_the_machine(given, kind, namespace, scenario):
    g = launch(**given)
    assert isinstance(g, kind) and g.namespace == namespace and g.scenario == scenario


def test_every_machine_takes_the_common_arguments_and_names_the_rest():
    for m in MACHINES.values():
        assert set(m.takes) < {name for name, *_ in ARGUMENTS}


@pytest.mark.parametrize('given, message', [
    ({'rig': 'true', 'scenario': 'step'}, 'scenario: not available with rig:=true'),
    ({'rig': 'true', 'hardware': 'true', 'record': 'b'},
     'record: not available with rig:=true hardware:=true'),
    ({'station': 'true', 'rig': 'true'}, 'rig:=true: not available with station:=true'),
    ({'hardware': 'true', 'sync_mode': 'lockstep', 'controller': 'pid'},
     'sync_mode, controller: not available with hardware:=true'),
    ({'port': '/dev/ttyUSB0'}, 'port: only with hardware:=true'),
    ({'station': 'true', 'model_file': 'm.yaml'}, 'model_file: not available with station'),
    ({'live_port': '9000'}, 'live_port: only with live:=true'),
    ({'rig': 'true', 'seed': '-1'}, "seed -1 is not allowed"),
])
def test_an_argument_the_machine_does_not_take_is_refused_in_one_line(given, message):
    with pytest.raises(GraphError, match=message):
        launch(**given)


def test_on_the_1d_graph_seed_is_the_plants_noise_seed_when_given():
    shipped = launch().node_params(PLANT)['seed']
    assert launch(seed='7').node_params(PLANT)['seed'] == 7 != shipped
    # a user's override wins over the argument, as a later params source does
    g = describe(dict(DEFAULTS, seed='7'), {PLANT: {'seed': 9}})
    assert g.node_params(PLANT)['seed'] == 9


def test_the_run_seed_sets_the_rig_and_the_hardware_graph_ignores_it():
    assert launch(rig='true', seed='3').seed == 3 and launch(rig='true').seed == 0
    assert launch(hardware='true', seed='3').params() == launch(hardware='true').params()


def _same(a, b, without=()):
    """Assert two graphs run the same processes with the same params (``without`` aside)."""
    assert type(a) is type(b)
    assert [p.command('P', a.namespace) for p in a.processes] == \
        [p.command('P', b.namespace) for p in b.processes]
    pa, pb = a.params(), b.params()
    for sections in (pa, pb):
        for sec in sections.values():
            for k in without:
                sec['ros__parameters'].pop(k, None)
    assert pa == pb


@pytest.mark.parametrize('options, given', [
    ([], {}),
    (['--sync', 'lockstep', '--controller', 'pid', '--namespace', 'left', '--multi-process'],
     dict(sync_mode='lockstep', controller='pid', namespace='left', composed='false')),
    (['--rig', '--sync', 'lockstep', '--seed', '3'],
     dict(rig='true', sync_mode='lockstep', seed='3')),
    (['--station', '--seed', '2'], dict(station='true', seed='2')),
    (['--hardware', '--rig', '--port', '/dev/ttyX'],
     dict(hardware='true', rig='true', port='/dev/ttyX')),
])
def test_bringup_starts_the_graph_launch_starts_for_the_same_arguments(options, given):
    # bringup holds the simulated plants until the graph is connected (autostart); the
    # run catalogue's copy of every node's parameters (graph_parameters) carries it too
    _same(bringup_graph(parse_args(options))[0], launch(**given),
          without=('autostart', 'graph_parameters'))


def test_bringup_holds_the_simulated_plants_and_ends_a_1d_scenario_itself():
    g, src = describe_run(dict(DEFAULTS, scenario='sine'), duration_s=0.5)
    runner = g.node_params('scenario_runner')
    assert runner['duration_s'] == 0.5 and runner['exit_when_done'] is False
    assert runner['wait_for_recorder'] is False and not src.open_loop
    assert g.node_params(PLANT)['autostart'] is False
    rig, none = describe_run(dict(DEFAULTS, rig='true'))
    assert none is None and rig.node_params('x/' + PLANT)['autostart'] is False
    idle, none = describe_run(DEFAULTS)          # no scenario: it starts as under launch
    assert none is None and idle.node_params(PLANT)['autostart'] is True
