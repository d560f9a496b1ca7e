# SPDX-License-Identifier: Apache-2.0
"""
The executables of ``setup.py`` (its ``NODES`` list): one role each, none imports another.

An executable is its module ``fiber_align/nodes/<name>.py`` (or the package
``fiber_align/nodes/<name>/``, or ``fiber_align/<name>/`` for the harness beside
``nodes/``). What two executables share lives in a ROS helper (``nodes/ros/``) or in the
core, never in one of them: the imports each states are parsed (ast) and checked against
the others' modules. The sizes: each domain executable is one file of at most 250 lines.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'fiber_align'
#: The labelled stand-ins and the harness, not counted as domain executables (issue 38).
NOT_DOMAIN = ('bringup', 'control_graph', 'lifecycle_manager', 'bag_recorder', 'live_view')
#: One executable per role (issue 38): the sequencer, the optics, the simulated plant.
ONE_PER_ROLE = {'sequencer': 'alignment_sequencer', 'optics': 'simulated_optics',
                'plant': 'simulated_actuator', 'driver': 'actuator_driver'}


def setup_nodes():
    """Return the executable names of ``setup.py``'s ``NODES`` list (parsed, not run)."""
    tree = ast.parse((ROOT / 'setup.py').read_text(encoding='utf-8'))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, 'id', '') == 'NODES'
                                                for t in node.targets):
            return [ast.literal_eval(e) for e in node.value.elts]
    raise AssertionError('setup.py has no NODES list')


def sources(name):
    """Return ``(dotted module, [files])`` of executable ``name``; fail when none exists."""
    for dotted, path in (('fiber_align.nodes.' + name, PACKAGE / 'nodes' / (name + '.py')),
                         ('fiber_align.nodes.' + name, PACKAGE / 'nodes' / name),
                         ('fiber_align.' + name, PACKAGE / name)):
        if path.is_file():
            return dotted, [path]
        if path.is_dir() and (path / '__init__.py').is_file():
            return dotted, sorted(path.rglob('*.py'))
    raise AssertionError('executable %s: no module fiber_align/nodes/%s.py or package' %
                         (name, name))


def imported(path):
    """Yield every absolute module name ``path`` imports (``from a import b``: a and a.b)."""
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            yield node.module
            yield from ('%s.%s' % (node.module, a.name) for a in node.names)


def test_setup_nodes_lists_each_executable_once_and_each_has_its_module():
    names = setup_nodes()
    assert len(names) == len(set(names)), names
    for name in names:
        sources(name)


@pytest.mark.parametrize('name', setup_nodes())
def test_no_executable_imports_another(name):
    me, files = sources(name)
    others = {sources(n)[0]: n for n in setup_nodes() if n != name}
    bad = sorted({(f.relative_to(ROOT).as_posix(), m) for f in files for m in imported(f)
                  for o in others if m == o or m.startswith(o + '.')})
    assert not bad, '%s imports another executable (move the shared part to nodes/ros/ ' \
        'or the core): %s' % (name, bad)


def test_the_parser_sees_an_executable_importing_another(tmp_path):
    """The check above can fail: a module importing another executable is caught."""
    f = tmp_path / 'x.py'
    f.write_text('from fiber_align.nodes.simulated_actuator import JOINT_NAME\n'
                 'import fiber_align.nodes.alignment_sequencer\n', encoding='utf-8')
    got = set(imported(f))
    assert 'fiber_align.nodes.simulated_actuator.JOINT_NAME' in got
    assert 'fiber_align.nodes.alignment_sequencer' in got


def test_one_executable_per_role_and_domain_executables_at_most_250_lines_each():
    names = setup_nodes()
    for role, exe in ONE_PER_ROLE.items():
        assert exe in names, role
    retired = ('alignment_sequencer2d', 'station_sequencer', 'rig_optics', 'station_optics',
               'rig_actuator', 'mdt693b_driver')
    assert not set(retired) & set(names)
    sizes = {}
    for name in names:
        if name in NOT_DOMAIN:
            continue
        _, files = sources(name)
        assert len(files) == 1, '%s: one file, not a package' % name
        sizes[name] = len(files[0].read_text(encoding='utf-8').splitlines())
    over = {n: k for n, k in sizes.items() if k > 250}
    assert not over, 'domain executables over 250 lines: %s' % over
