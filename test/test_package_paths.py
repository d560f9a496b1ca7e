# SPDX-License-Identifier: Apache-2.0
"""
No stale path: every module and file that docs/, config/, launch/ and the package name exists.

A module moved or renamed leaves its old name in docstrings, comments and pages
(``graph_rig.py``, ``fiber_align/nodes/graph_params.py``, ``nodes/graph.py``,
``launch/fiber_align_hardware.launch.py``): a reader follows it to nothing. Each text
file of ``docs/``, ``config/``, ``launch/``, ``fiber_align/`` and the README is searched
for

- dotted module names: ``fiber_align.a.b`` and the package's own relative ones
  (``graph.params.SHARED``, ``nodes.ros.runtime.run_node``: they start with one of its
  areas), each resolved to a module and, past it, to a name that module defines;
- file paths ``a/b.py`` (``.py``, ``.yaml``, ``.xml``, ``.md``), resolved from the
  repository, from ``fiber_align/`` or from ``fiber_align/nodes/``;
- bare file names ``name.py``: some file of the repository has that name.

Each name that resolves to nothing fails the test, with the file and line.
"""

import ast
from functools import lru_cache
from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'fiber_align'
#: Where the names are looked for (directories searched recursively, and files).
SEARCHED = ('docs', 'config', 'launch', 'fiber_align', 'README.md')
#: Text files searched.
SUFFIXES = {'.py', '.md', '.yaml', '.xml', '.txt', '.cfg', '.json'}
#: Relative dotted names start with one of the package's areas (``graph.params``).
AREAS = tuple(sorted(p.name for p in PACKAGE.iterdir()
                     if (p / '__init__.py').exists() or p.suffix == '.py'))
#: Second parts that make ``fiber_align.<x>`` a file name, not a module
#: (``fiber_align.yaml``, ``fiber_align.launch.py``).
FILE_PARTS = {'yaml', 'launch', 'xml', 'md', 'json', 'egg-info', 'egg', 'txt', 'py'}
#: Path prefixes of a run's output (``runs/model.yaml``): files the user makes.
OUTPUT_PREFIXES = ('runs/',)
#: Bare file names that name no file of this repository on purpose.
FOREIGN_FILES = {'conftest.py', '__init__.py'}

#: ``fiber_align.a.b`` (not in a string literal: a thread's or a schema's name is data)
DOTTED = re.compile(r'(?<![\w.\'"])(fiber_align(?:\.[A-Za-z_][A-Za-z0-9_]*)+)')
#: ``area.a.b`` inside backquotes (``graph.params.SHARED``; in code, a variable named
#: like an area is no module)
RELATIVE = re.compile(r'(?<![\w.])((?:%s)(?:\.[A-Za-z_][A-Za-z0-9_]*)+)'
                      % '|'.join(re.escape(Path(a).stem) for a in AREAS))
#: The repository's own top-level directories: a path that starts with one is whole.
TOP = ('fiber_align', 'docs', 'config', 'launch', 'test', 'bench', 'layouts', 'resource')
QUOTED = re.compile(r'`([^`\n]+)`')
PATH = re.compile(r'(?<![\w.~$/-])((?:[A-Za-z_][\w.-]*/)+[\w.-]+\.(?:py|yaml|xml|md))\b')
BARE_PY = re.compile(r'(?<![\w./-])([A-Za-z_]\w*\.py)\b')


def searched_files():
    """Yield every text file searched, in a stable order."""
    for name in SEARCHED:
        p = ROOT / name
        files = [p] if p.is_file() else sorted(q for q in p.rglob('*') if q.is_file())
        for f in files:
            if f.suffix in SUFFIXES and '__pycache__' not in f.parts:
                yield f


@lru_cache(maxsize=None)
def repo_files():
    """Return the paths (``a/b.py``) of every file of the repository, hidden dirs aside."""
    return frozenset('/'.join(p.relative_to(ROOT).parts) for p in ROOT.rglob('*')
                     if not p.relative_to(ROOT).parts[0].startswith('.') and p.is_file()
                     and '__pycache__' not in p.parts)


@lru_cache(maxsize=None)
def repo_basenames():
    """Return the names of every file of the repository."""
    return frozenset(f.rsplit('/', 1)[-1] for f in repo_files())


def module_file(parts):
    """Return the source of module ``fiber_align.<parts>`` (file or package), or None."""
    base = PACKAGE.joinpath(*parts)
    for f in (base.with_suffix('.py'), base / '__init__.py'):
        if f.is_file():
            return f
    return None


@lru_cache(maxsize=None)
def defined_names(path):
    """Return the top-level names module ``path`` defines or imports."""
    tree = ast.parse(Path(path).read_text(encoding='utf-8'))
    out = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                for n in ast.walk(t):
                    if isinstance(n, ast.Name):
                        out.add(n.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            out.update((a.asname or a.name).split('.')[0] for a in node.names)
    return out


def dotted_ok(name):
    """Return True when dotted ``name`` is a module of the package, or a name in one."""
    parts = name.split('.')
    if parts[0] == 'fiber_align':
        parts = parts[1:]
        if not parts or parts[0] in FILE_PARTS or parts[0][0].isupper():
            return True                 # a file, or a message type (``fiber_align.X``)
    if parts[-1] in FILE_PARTS:         # a file name (``station.yaml``, ``x.launch.py``)
        return True
    i = 0
    while i < len(parts) and module_file(parts[:i + 1]) is not None:
        i += 1
    if i == 0:
        return False
    if i == len(parts):
        return True
    return parts[i] in defined_names(str(module_file(parts[:i])))


def path_ok(path):
    """
    Return True when ``path`` is a file of the repository or ends one (``x/y.py``).

    A path from the repository's root must be whole (``fiber_align/nodes/x.py``); a
    shorter one (``emulators/mdt693b.py``, ``models/compensator_model.yaml``) must end
    the path of a file.
    """
    if path.startswith(OUTPUT_PREFIXES):
        return True
    if path.split('/')[0] in TOP:
        return path in repo_files()
    return any(f == path or f.endswith('/' + path) for f in repo_files())


def stale_names(path):
    """Yield ``(line number, name, why)`` for each name in ``path`` that resolves to nothing."""
    text = path.read_text(encoding='utf-8', errors='replace')
    for n, line in enumerate(text.splitlines(), 1):
        names = [m.group(1) for m in DOTTED.finditer(line)]
        names += [m.group(1) for q in QUOTED.finditer(line)
                  for m in RELATIVE.finditer(q.group(1))]
        for name in names:
            if not dotted_ok(name):
                yield n, name, 'no such module or name'
        for m in PATH.finditer(line):
            p = m.group(1)
            if not path_ok(p):
                yield n, p, 'no such file'
        for m in BARE_PY.finditer(line):
            p = m.group(1)
            if p not in repo_basenames() and p not in FOREIGN_FILES:
                yield n, p, 'no file of this name'


def test_the_checks_see_stale_names(tmp_path):
    f = tmp_path / 'page.md'
    f.write_text('`fiber_align.graph.params.SHARED` and `graph.rig.build_rig` exist;\n'
                 '`fiber_align.nodes.graph_params`, `graph.params.NOPE`, '
                 '`fiber_align/nodes/graph.py`, `graph_rig.py` and\n'
                 '`launch/fiber_align_hardware.launch.py` do not; `fiber_align.yaml`,\n'
                 '`launch/fiber_align.launch.py` and `config/plant.yaml` do.\n')
    found = [name for _, name, _ in stale_names(f)]
    assert found == ['fiber_align.nodes.graph_params', 'graph.params.NOPE',
                     'fiber_align/nodes/graph.py', 'graph_rig.py',
                     'launch/fiber_align_hardware.launch.py']


@pytest.mark.parametrize('path', list(searched_files()),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_no_stale_path(path):
    stale = ['%s:%d: %s (%s)' % (path.relative_to(ROOT), n, name, why)
             for n, name, why in stale_names(path)]
    assert not stale, 'names that resolve to nothing:\n' + '\n'.join(stale)
