# SPDX-License-Identifier: Apache-2.0
"""The flight recorder added to a described graph (``graph.snapshots.with_snapshots``)."""

import pytest

from fiber_align.graph.arguments import describe
from fiber_align.graph.params import GraphError


def _where(graph):
    return [p.name for p in graph.processes if 'bag_recorder' in p.nodes]


def test_a_snapshots_only_recorder_is_a_process_of_its_own(tmp_path):
    """
    Beside a composed graph too: its snapshot writes stay off the control process.

    Hosted in control_graph, a 12 s snapshot written by a Python thread held the control
    thread's GIL: 166-242 periods of a 17 s run missed.
    """
    for args in ({'scenario': 'sine'}, {'hardware': 'true'}):
        g = describe(dict(args, snapshots=str(tmp_path / 's')))
        assert _where(g) == ['bag_recorder'], [p.nodes for p in g.processes]
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
