# SPDX-License-Identifier: Apache-2.0
"""The flight recorder added to a described graph (``graph.snapshots.with_snapshots``)."""

import pytest

from fiber_align.graph.arguments import describe
from fiber_align.graph.params import GraphError


def _where(graph):
    return [p.name for p in graph.processes if 'bag_recorder' in p.nodes]


def test_a_composed_1d_graph_hosts_its_snapshots_only_recorder(tmp_path):
    """Composed: in the control process (the bus, not DDS); its bag off, snapshots on."""
    for args in ({'scenario': 'sine'}, {'hardware': 'true'}):
        g = describe(dict(args, snapshots=str(tmp_path / 's')))
        assert _where(g) == ['control_graph'], [p.nodes for p in g.processes]
        host = g.processes[0]
        assert host.arguments == ('--nodes', ','.join(host.nodes))
        rec = g.node_params('bag_recorder')
        assert rec['record'] is False and rec['snapshots'] == str(tmp_path / 's')


def test_a_multi_process_graph_gets_a_recorder_process(tmp_path):
    g = describe({'snapshots': str(tmp_path / 's'), 'composed': 'false'})
    assert _where(g) == ['bag_recorder']


def test_a_recording_graph_keeps_its_one_recorder_and_its_bag(tmp_path):
    g = describe({'snapshots': str(tmp_path / 's'), 'record': str(tmp_path / 'bag')})
    assert _where(g) == ['control_graph']
    assert g.node_params('bag_recorder').get('record', True) is not False


def test_the_rig_without_record_is_refused_in_one_line(tmp_path):
    with pytest.raises(GraphError, match='only with record'):
        describe({'snapshots': str(tmp_path / 's'), 'rig': 'true'})
