# SPDX-License-Identifier: Apache-2.0
"""
One truth per parameter in the shipped params files (``config/*.yaml``, read with yaml).

A graph merges several files (:data:`fiber_align.graph.description.AREA_FILES`, then
:data:`~fiber_align.graph.description.GRAPH_FILE`); when two of them set one value, the
later silently wins and an edit of the earlier changes nothing. So, for each graph:

- a graph-wide value (:data:`fiber_align.graph.params.SHARED`) is set by one file, once;
- a node's own parameter is set by one file;
- an overlay (the hardware graph's :data:`~fiber_align.graph.hardware.HARDWARE_FILES`)
  changes graph-wide values in its ``/**`` section only, each once, and sets each node
  parameter in one overlay file;
- a period derived from ``rate_hz`` (the sequencers' ``control_period_s``, the optics'
  ``sample_period_s``) is not stored.
"""

from pathlib import Path

import pytest
import yaml

from fiber_align.config import flatten
from fiber_align.graph import description, hardware, hardware_rig, rig
from fiber_align.graph.params import SHARED

CONFIG = Path(__file__).resolve().parents[1] / 'config'
#: The files of the 1-D graph, in merge order.
BASE = description.AREA_FILES + (description.GRAPH_FILE,)
#: Each graph: (its base files, its overlay files).
GRAPHS = {
    '1-D': (BASE, ()),
    'rig': (BASE + rig.RIG_FILES, ()),
    'hardware': (BASE, hardware.HARDWARE_FILES),
    'hardware rig': (BASE + rig.RIG_FILES, hardware_rig.HARDWARE_RIG_FILES),
}
#: Periods that are 1 / rate_hz of the graph; a file must not hold a copy.
DERIVED = ('control_period_s', 'sample_period_s')
#: Copies still stored, with the code that reads them (drop an entry when it derives it).
KNOWN_STORED = set()


def settings(name):
    """Yield ``(section, dotted key)`` for every value ``config/<name>`` sets."""
    data = yaml.safe_load((CONFIG / name).read_text(encoding='utf-8')) or {}
    for section, body in data.items():
        params = (body or {}).get('ros__parameters') or {}
        parts = str(section).strip('/').split('/')
        # a rig axis's own section (x/<node>) is its own, not the node's of both axes
        name = '/'.join(parts[-2:]) if len(parts) > 1 and parts[-2] in rig.AXES else parts[-1]
        for key in flatten(params):
            yield ('/**' if section in ('/**', '**') else name), key


def shared_key(section, key):
    """Return ``key`` when it is a graph-wide value where it is set, else None."""
    if key in SHARED and (section == '/**' or section in SHARED[key]):
        return key
    return None


def where_set(files):
    """Return ``{value: [(file, section), ...]}`` over ``files`` (graph-wide by name)."""
    out = {}
    for name in files:
        for section, key in settings(name):
            what = shared_key(section, key) or (section, key)
            out.setdefault(what, []).append((name, section))
    return out


@pytest.mark.parametrize('graph', sorted(GRAPHS))
def test_each_value_of_a_graph_is_set_in_one_base_file(graph):
    base, _ = GRAPHS[graph]
    twice = {what: places for what, places in where_set(base).items() if len(places) > 1}
    assert not twice, '%s graph: set in more than one place (set each once): %s' % (
        graph, twice)


@pytest.mark.parametrize('graph', [g for g in sorted(GRAPHS) if GRAPHS[g][1]])
def test_an_overlay_changes_graph_wide_values_once_in_its_own_star_section(graph):
    _, overlay = GRAPHS[graph]
    places = where_set(overlay)
    twice = {what: p for what, p in places.items() if len(p) > 1}
    assert not twice, '%s overlay sets a value twice: %s' % (graph, twice)
    under_node = {what: p for what, p in places.items()
                  if isinstance(what, str) and p[0][1] != '/**'}
    assert not under_node, ('%s overlay sets graph-wide values under a node: %s (set them '
                            'under /**)' % (graph, under_node))


def test_the_control_rate_is_set_once_in_the_plant_file():
    places = where_set(BASE)['rate_hz']
    assert places == [('plant.yaml', 'simulated_actuator')]


def test_periods_derived_from_the_rate_are_not_stored():
    stored = {(path.name, section, key)
              for path in sorted(CONFIG.glob('*.yaml'))
              for section, key in settings(path.name)
              if key.split('.')[-1] in DERIVED}
    assert stored - KNOWN_STORED == set(), 'derive these from rate_hz, do not store them'
    assert KNOWN_STORED - stored == set(), 'no longer stored: drop from KNOWN_STORED'


def test_the_check_sees_a_value_set_in_two_files(tmp_path, monkeypatch):
    (tmp_path / 'a.yaml').write_text('x:\n  ros__parameters:\n    rate_hz: 1.0\n    k: 1\n')
    (tmp_path / 'b.yaml').write_text('/**:\n  ros__parameters:\n    rate_hz: 2.0\n'
                                     'x:\n  ros__parameters:\n    k: 2\n')
    monkeypatch.setattr(f'{__name__}.CONFIG', tmp_path)
    monkeypatch.setitem(SHARED, 'rate_hz', ('x',))
    places = where_set(('a.yaml', 'b.yaml'))
    assert places['rate_hz'] == [('a.yaml', 'x'), ('b.yaml', '/**')]
    assert places[('x', 'k')] == [('a.yaml', 'x'), ('b.yaml', 'x')]


NODES_DIR = Path(__file__).resolve().parents[1] / 'fiber_align' / 'nodes'


def graph_values_declared(path):
    """
    Return the graph-wide names a node module declares (``declare_graph_values`` calls).

    A starred argument (``*GRAPH``) is resolved through the module's own tuple of that
    name; an imported one (``*PRIORITY``, the scheduling values) is not a shared value.
    """
    import ast
    tree = ast.parse(path.read_text(encoding='utf-8'))
    tuples = {t.id: node.value for node in tree.body if isinstance(node, ast.Assign)
              for t in node.targets if isinstance(t, ast.Name)}
    out = set()
    for call in ast.walk(tree):
        if not (isinstance(call, ast.Call) and getattr(call.func, 'id', '') ==
                'declare_graph_values'):
            continue
        for arg in call.args:
            if isinstance(arg, ast.Starred) and isinstance(arg.value, ast.Name):
                arg = tuples.get(arg.value.id)      # a tuple, or tuples added together
            out.update(i.value for i in (ast.walk(arg) if arg is not None else ())
                       if isinstance(i, ast.Constant) and isinstance(i.value, str))
    return out


def declared_by_node():
    """Return ``{node name: graph-wide names it declares}`` over the registry's nodes."""
    out = {}
    for spec in description.NODES.values():
        path = NODES_DIR / (spec.executable + '.py')
        if not path.exists():
            continue
        text = path.read_text(encoding='utf-8')
        names = graph_values_declared(path)
        # the helper modules of an executable (fiber_align.nodes._<name>) declare for it
        for helper in sorted(NODES_DIR.glob('_*.py')):
            if 'fiber_align.nodes.%s import' % helper.stem in text:
                names |= graph_values_declared(helper)
        out.setdefault(spec.node, set()).update(names)
    return out


@pytest.mark.parametrize('name', ['rate_hz', 'sync_mode'])
def test_every_node_that_declares_the_graph_rate_or_sync_mode_gets_the_graph_value(name):
    declaring = {node for node, names in declared_by_node().items() if name in names}
    # the scan sees the loop's nodes and the nodes of several axes (a scan that saw none
    # would pass anything)
    assert {'simulated_actuator', 'station_sequencer', 'simulated_optics_2d'} <= declaring
    assert declaring - set(SHARED[name]) == set(), (
        'these nodes declare %s but graph.params.SHARED does not give them the graph '
        'value' % name)


@pytest.mark.parametrize('node', ['station_sequencer', 'simulated_station_optics',
                                  'alignment_sequencer_2d', 'simulated_optics_2d'])
def test_a_user_file_cannot_give_a_multi_axis_node_a_rate_of_its_own(tmp_path, node):
    from fiber_align.graph.params import effective, GraphError, merge_params
    files = [CONFIG / f for f in BASE + rig.RIG_FILES]
    user = tmp_path / 'user.yaml'
    user.write_text('%s:\n  ros__parameters:\n    rate_hz: 500.0\n' % node)
    merged = merge_params(files + [user])
    for n in (node, 'simulated_actuator', 'actuator_driver'):
        assert effective(merged, n)['rate_hz'] == 500.0, n
    merged = merge_params(files, overrides={node: {'rate_hz': 250.0}})
    assert effective(merged, 'simulated_actuator')['rate_hz'] == 250.0
    user.write_text('%s:\n  ros__parameters:\n    rate_hz: 500.0\n'
                    'simulated_actuator:\n  ros__parameters:\n    rate_hz: 1000.0\n' % node)
    with pytest.raises(GraphError, match='rate_hz is one value'):
        merge_params(files + [user])
