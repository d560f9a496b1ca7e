# SPDX-License-Identifier: Apache-2.0
"""The live view in the graph description (``fiber_align.graph.live``; pure, no process)."""

import importlib.util
from pathlib import Path
import socket
import sys
import types

import pytest

from fiber_align.graph import description as gd, rig as gr
from fiber_align.graph.hardware import build_hardware
from fiber_align.graph.arguments import describe
from fiber_align.graph.live import (check_endpoint, graph_published, graph_topics,
                                    live_settings, readers, with_live)
from fiber_align.graph.params import GraphError
from fiber_align.graph.registry import is_command

ROOT = Path(__file__).resolve().parents[1]


def test_live_adds_one_process_of_its_own_with_the_graphs_topics():
    base = gd.build()
    assert with_live(base, False) is base and with_live(base, 'false') is base
    g = with_live(base, True)
    assert [p.executable for p in g.processes] == [p.executable for p in base.processes] + [
        'live_view']
    view = g.processes[-1]
    assert view.nodes == ('live_view',) and view.namespace is None
    # never inside control_graph
    assert all('live_view' not in p.nodes for p in g.processes[:-1])
    p = g.node_params('live_view')
    assert p['topics'] == list(graph_topics(base))
    assert set(graph_published(base)) == {
        'displacement', 'optical_power', 'feedforward_voltage', 'reference',
        'feedback_voltage', 'controller_state', 'drive_voltage'}
    assert (p['host'], p['port'], p['power_map']) == ('127.0.0.1', 8765, False)
    assert p['ui_rate_hz'] == 100.0
    assert live_settings(g) == ('127.0.0.1', 8765) and live_settings(base) is None
    # the graph without the view is unchanged
    assert gd.build().params() == base.params()


def test_live_on_the_rig_serves_both_axes_and_the_power_map_over_the_search_square():
    r = with_live(gr.build_rig(), True, '9001', '0.0.0.0')
    assert r.processes[-1].namespace == 'rig'
    p = r.node_params('live_view')
    assert (p['host'], p['port'], p['power_map']) == ('0.0.0.0', 9001, True)
    seq = r.node_params('alignment_sequencer_2d')
    assert [p[k] for k in ('range_x_min_m', 'range_x_max_m', 'range_y_min_m',
                           'range_y_max_m')] == [
        seq['range_x_min_m'], seq['range_x_max_m'], seq['range_y_min_m'],
        seq['range_y_max_m']]
    for t in ('x/displacement', 'y/displacement', 'optical_power', 'x/reference',
              'y/drive_voltage', 'x/tip_position'):
        assert t in p['topics'], t


def test_live_on_the_hardware_graph():
    h = with_live(build_hardware(), True)
    assert h.processes[-1].executable == 'live_view'
    assert 'optical_power' in graph_published(h) and 'displacement' not in graph_published(h)


@pytest.mark.parametrize('args, words', [
    ((False, '9000', ''), 'live_port: only with live:=true'),
    ((False, '', 'h'), 'live_host: only with live:=true'),
    ((True, 'eighty', ''), "live_port 'eighty' is not allowed"),
    ((True, '70000', ''), "live_port '70000' is not allowed"),
    ((True, '', 'two words'), "live_host 'two words' is not allowed"),
    (('maybe', '', ''), "live 'maybe' is not allowed"),
])
def test_bad_live_arguments_get_one_clear_line(args, words):
    with pytest.raises(GraphError, match=words):
        with_live(gd.build(), *args)


def test_a_port_in_use_is_refused_before_anything_starts():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        s.listen(1)
        port = s.getsockname()[1]
        with pytest.raises(GraphError, match='live view ws://127.0.0.1:%d' % port):
            check_endpoint('127.0.0.1', port)
    check_endpoint('127.0.0.1', port)       # free again


def test_the_launch_file_adds_the_view_through_the_description(monkeypatch):
    # launch_ros needs the ros2-tools' composition_interfaces; describe() does not
    stub = types.ModuleType('launch_ros.actions')
    stub.Node = object
    monkeypatch.setitem(sys.modules, 'launch_ros', types.ModuleType('launch_ros'))
    monkeypatch.setitem(sys.modules, 'launch_ros.actions', stub)
    spec = importlib.util.spec_from_file_location(
        'fiber_align_launch', ROOT / 'launch' / 'fiber_align.launch.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    args = {name: default for name, default, *_ in mod.ARGUMENTS}
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
    for extra in ({}, {'rig': 'true'}, {'hardware': 'true'}):
        g = mod.describe(dict(args, live='true', live_port=str(port), **extra))
        assert g.processes[-1].executable == 'live_view'
        assert live_settings(g) == ('127.0.0.1', port)
    assert 'live_view' not in [p.executable for p in mod.describe(args).processes]
    text = (ROOT / 'launch' / 'fiber_align.launch.py').read_text()
    assert "'live_view'" not in text            # no special case: the description's


#: Every machine with everything that can read its topics: the live view, and the recorder
#: where the machine records.
VARIANTS = [dict(m, live='true', live_port='18765') for m in (
    {'record': '/nonexistent/bag'}, {'rig': 'true'}, {'station': 'true', 'record': '/x/bag'},
    {'hardware': 'true', 'record': '/x/bag'}, {'rig': 'true', 'hardware': 'true'})]


@pytest.mark.parametrize('arguments', VARIANTS, ids=lambda a: '-'.join(
    k for k in ('rig', 'station', 'hardware') if k in a) or '1d')
def test_every_command_topic_keeps_one_reader_the_loops(arguments):
    """A `ros2 topic pub --once` setpoint reaches the loop: the view reads `reference`."""
    g = describe(arguments)
    found = {t: r for t, r in readers(g).items() if is_command(t)}
    assert found, 'no setpoint topic in %s' % arguments
    for t, r in found.items():
        assert len(r) == 1 and r[0].endswith('hysteresis_compensator'), (t, r)
    served = g.node_params('live_view')['topics']
    assert not [t for t in served if is_command(t)], served
    assert [t for t in served if t.endswith('reference')], served
