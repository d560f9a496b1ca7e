# SPDX-License-Identifier: Apache-2.0
"""
The package's layering, checked from the imports that the source states (parsed by ast).

The rule (docs/CONTRACTS.md): ``config < design, hysteresis, records < plant, control < alignment
< simulation, hardware < analysis < graph < nodes < bringup < tools``. A module imports
only its own area and areas of a lower rank; areas of one rank do not import each other;
every import of the package's own modules is at module level; there is no import cycle;
no module imports an executable of ``nodes/`` but its own area (``bringup`` uses the ROS
helpers ``nodes/ros/`` and ``nodes/_*.py``, never a node).
"""

import ast
from pathlib import Path

PACKAGE = 'fiber_align'
ROOT = Path(__file__).resolve().parent.parent / PACKAGE

# area -> rank; an area is the first name below the package (a sub-package or a module).
RANKS = {
    '': 0, 'config': 0, 'jsonout': 0, 'lifeline': 0, 'procstat': 0,
    'design': 1, 'hysteresis': 1, 'records': 1,
    'plant': 2, 'control': 2,
    'alignment': 3,
    'simulation': 4, 'hardware': 4,
    'analysis': 5,
    'graph': 6,
    'nodes': 7,
    'bringup': 8,
    'tools': 9,
}
# The two command-line entry points beside the tools package belong to it.
TOOLS_MODULES = {'cli': 'tools', 'demo': 'tools'}

# Modules allowed to import one of the package's own modules by a constant name at run
# time (the rule does not see such an import): none.
DYNAMIC_IMPORT_ALLOWED = set()


def module_name(path):
    """Return the dotted module name of a source file below the package."""
    parts = list(path.relative_to(ROOT.parent).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def area(module):
    """Return the area of a dotted module name (``''`` for the package itself)."""
    parts = module.split('.')
    name = parts[1] if len(parts) > 1 else ''
    return TOOLS_MODULES.get(name, name)


def modules():
    """Return ``{module name: path}`` of every source file of the package."""
    return {module_name(p): p for p in sorted(ROOT.rglob('*.py'))}


def own_imports(path, known):
    """
    Yield ``(target module, line, at module level)`` for each import of the package.

    ``from pkg import name`` counts as an import of ``pkg.name`` when that is a module.
    """
    tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
    top = {id(n) for n in tree.body}
    me = module_name(path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = me.split('.')
                if path.name != '__init__.py':
                    base = base[:-1]
                base = base[:len(base) - node.level + 1]
                mod = '.'.join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ''
            targets = []
            for a in node.names:
                sub = '%s.%s' % (mod, a.name)
                targets.append(sub if sub in known else mod)
        else:
            continue
        for t in targets:
            if t == PACKAGE or t.startswith(PACKAGE + '.'):
                yield t, node.lineno, id(node) in top


def dynamic_imports(path):
    """Return the lines that import a module of the package by a name (importlib)."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else getattr(f, 'id', '')
        if name not in ('import_module', '__import__'):
            continue
        texts = [c.value for a in node.args for c in ast.walk(a)
                 if isinstance(c, ast.Constant) and isinstance(c.value, str)]
        if any(t.startswith(PACKAGE) for t in texts):
            lines.append(node.lineno)
    return lines


def forbidden_edges():
    """Return a list of human-readable violations of the layering rule."""
    known = modules()
    bad = []
    for me, path in known.items():
        if me not in DYNAMIC_IMPORT_ALLOWED:
            bad += ['%s:%d: imports one of its own modules by name, hidden from this check'
                    % (path.relative_to(ROOT.parent), line) for line in dynamic_imports(path)]
        for target, line, at_top in own_imports(path, known):
            a, b = area(me), area(target)
            where = '%s:%d' % (path.relative_to(ROOT.parent), line)
            if a not in RANKS or b not in RANKS:
                bad.append('%s: area %r or %r has no rank in RANKS'
                           % (where, a, b))
                continue
            if not at_top:
                bad.append('%s: function-local import of %s' % (where, target))
            if a != b and RANKS[b] >= RANKS[a]:
                kind = 'sideways' if RANKS[b] == RANKS[a] else 'upward'
                bad.append('%s: %s import %s (%s, rank %d) -> %s (%s, rank %d)'
                           % (where, kind, me, a or PACKAGE, RANKS[a], target,
                              b or PACKAGE, RANKS[b]))
    return bad


def import_cycles():
    """Return the module-level import cycles between the package's modules."""
    known = modules()
    graph = {m: sorted({t for t, _, top in own_imports(p, known) if top and t != m})
             for m, p in known.items()}
    cycles, state = [], {}

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for n in graph.get(m, ()):
            if state.get(n) == 1:
                cycles.append(stack[stack.index(n):] + [n])
            elif n in graph and not state.get(n):
                visit(n, stack)
        stack.pop()
        state[m] = 2
    for m in graph:
        if not state.get(m):
            visit(m, [])
    return cycles


def test_every_area_has_a_rank():
    """A new sub-package must be placed in the layering before it can import anything."""
    areas = {area(m) for m in modules()}
    assert areas <= set(RANKS), sorted(areas - set(RANKS))


def test_imports_only_point_down():
    """No upward or sideways import, no function-local import of the package's modules."""
    bad = forbidden_edges()
    assert not bad, '\n'.join(['%d forbidden import(s):' % len(bad)] + bad)


def executable(module):
    """Return True for a node executable's module (``fiber_align.nodes.<name>``)."""
    parts = module.split('.')
    return len(parts) >= 3 and parts[1] == 'nodes' and parts[2] not in ('ros', '__init__') \
        and not parts[2].startswith('_')


def test_no_executable_imported_from_outside_nodes():
    """
    Outside ``nodes/`` nothing imports an executable (the harness neither).

    What two programs share lives in the core or in the ROS helpers, not in one of them.
    """
    known = modules()
    where = '%s:%d: imports the executable %s'
    bad = sorted({where % (path.relative_to(ROOT.parent), line, t)
                  for me, path in known.items() if area(me) != 'nodes'
                  for t, line, _ in own_imports(path, known) if executable(t)})
    assert not bad, '\n'.join(bad)


def test_no_import_cycle():
    """The module-level import graph of the package is acyclic."""
    cycles = import_cycles()
    assert not cycles, '\n'.join(' -> '.join(c) for c in cycles)
