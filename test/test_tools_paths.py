# SPDX-License-Identifier: Apache-2.0
"""Every path argument of ``fiber-align``: a bad path is one clear line and exit code 2."""

import os

import pytest

from fiber_align import cli
from fiber_align.tools import paths

ROOT = os.geteuid() == 0

#: (sub-command (and action), its other arguments ({tmp}: the test's folder, {file}: an existing
#: file there), the path argument, its kind)
ARGS = [
    ('design', [], '--config', 'in-config'),
    ('design', [], '--plots', 'out-dir'),
    ('identify', ['--out', '{tmp}/m.yaml'], 'DATA', 'in-any'),
    ('identify', ['{file}', '--out', '{tmp}/m.yaml'], '--config', 'in-config'),
    ('identify', ['{file}'], '--out', 'out-file'),
    ('identify', ['{file}', '--out', '{tmp}/m.yaml'], '--plot', 'out-file'),
    ('simulate', [], '--model', 'in-config'),
    ('simulate', [], '--plot', 'out-file'),
    ('simulate', [], '--csv', 'out-file'),
    ('fuzzy-surface', [], '--plot', 'out-file'),
    ('analyze', [], 'BAG', 'in-any'),
    ('analyze', ['{file}'], '--plots', 'out-dir'),
    ('analyze', ['{file}'], '--report', 'out-file'),
    ('bag-repair', [], 'BAG', 'in-any'),
    ('bag-repair', ['{file}'], '--out', 'new-dir'),
    ('emulate', [], '--link-dir', 'in-dir'),
    ('runs export', [], '--csv', 'out-file'),
    ('runs report', ['--usl-loss-db', '0.5'], '--out', 'out-dir'),
]


_OUT = ['missing parent', 'file as parent', 'no permission']
#: the bad cases of each kind of path argument
CASES = {'in-file': ['folder for a file', 'missing'], 'in-config': ['folder for a file'],
         'in-any': ['missing'], 'in-dir': ['missing', 'file for a folder'],
         'out-file': _OUT + ['folder for a file'],
         'out-dir': _OUT + ['file for a folder', 'folder without permission'],
         'new-dir': _OUT + ['existing folder']}


def _locked(tmp):
    """Return a folder nobody may write in: read-only for a user, /proc for root."""
    if ROOT:
        return '/proc'      # permissions do not stop root; /proc takes no new file
    d = tmp / 'locked'
    d.mkdir()
    d.chmod(0o500)
    return str(d)


def _bad_values(kind, tmp):
    """Return ``{case: bad path}`` for an argument of ``kind`` (files made in ``tmp``)."""
    afile = tmp / 'a_file'
    afile.write_text('x')
    folder = tmp / 'a_folder'
    folder.mkdir()
    cases = {}
    if kind in ('in-file', 'in-config'):
        cases['folder for a file'] = str(folder)
    if kind in ('in-file', 'in-any', 'in-dir'):
        cases['missing'] = str(tmp / 'missing')
    if kind == 'in-dir':
        cases['file for a folder'] = str(afile)
    if kind.startswith('out-') or kind == 'new-dir':
        name = 'out.png' if kind == 'out-file' else 'out'
        cases['missing parent'] = str(tmp / 'no_such_folder' / name)
        cases['file as parent'] = str(afile / name)
        cases['no permission'] = os.path.join(_locked(tmp), name)
    if kind == 'out-file':
        cases['folder for a file'] = str(folder)
    if kind == 'out-dir':
        cases['file for a folder'] = str(afile)
        cases['folder without permission'] = _locked(tmp)
    if kind == 'new-dir':
        cases['existing folder'] = str(folder)
    assert set(cases) == set(CASES[kind])
    return cases


def _cases():
    for cmd, other, name, kind in ARGS:
        for case in CASES[kind]:
            yield pytest.param(cmd, other, name, kind, case,
                               id='%s-%s-%s' % (cmd, name.lstrip('-'), case.replace(' ', '_')))


@pytest.mark.parametrize('cmd, other, name, kind, case', list(_cases()))
def test_bad_path_is_one_line_and_exit_2(tmp_path, capsys, cmd, other, name, kind, case):
    """A bad path of each argument: exit 2, one line naming the argument and the path."""
    bad = _bad_values(kind, tmp_path)[case]
    (tmp_path / 'input').write_text('t,voltage_v,displacement_m\n')
    argv = cmd.split() + [a.format(tmp=tmp_path, file=tmp_path / 'input') for a in other]
    argv += [bad] if name.isupper() else [name, bad]
    code = cli.main(argv)
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert code == 2, (argv, out.err)
    assert len(lines) == 1 and 'Traceback' not in out.err, out.err
    assert lines[0].startswith('fiber-align %s: error: %s %s' % (cmd.split()[0], name, bad)), \
        lines[0]
    assert out.out == ''


def test_every_path_argument_is_declared_and_tested():
    """Each sub-command's path arguments are declared (kinds known) and all in ARGS."""
    def commands(parser, dest, prefix=''):
        sub = next(a for a in parser._actions if a.dest == dest)
        for cmd, p in sub.choices.items():
            if any(a.dest == 'action' for a in p._actions):     # a command with actions
                yield from commands(p, 'action', cmd + ' ')
            else:
                yield prefix + cmd, p
    declared = set()
    for cmd, p in commands(cli.build_parser(), 'command'):
        for name, kind in p.get_default('paths').items():
            assert kind in paths.KINDS
            assert any(paths.dest(name) == a.dest for a in p._actions), (cmd, name)
            declared.add((cmd, name, kind))
    assert declared == {(c, n, k) for c, _, n, k in ARGS}


def test_good_paths_pass(tmp_path):
    """Existing inputs and writable outputs (new or existing) pass the checks."""
    (tmp_path / 'f').write_text('x')
    for value, kind in ((tmp_path / 'f', 'in-file'), (tmp_path, 'in-dir'),
                        (tmp_path, 'in-any'), ('actuator.yaml', 'in-config'),
                        ('identify', 'in-config'), (tmp_path / 'n.png', 'out-file'),
                        (tmp_path / 'f', 'out-file'), (tmp_path, 'out-dir'),
                        (tmp_path / 'new', 'out-dir'), (tmp_path / 'new', 'new-dir')):
        paths.check_path('--x', str(value), kind)


def test_an_os_error_inside_a_command_is_one_line(monkeypatch, capsys):
    """An OSError a command meets after the checks still ends in one line and exit 2."""
    from fiber_align.tools import simulate_cli

    def fail(args):
        raise PermissionError(13, 'Permission denied', '/some/where.png')
    monkeypatch.setattr(simulate_cli, 'cmd_fuzzy_surface', fail)
    code = cli.main(['fuzzy-surface'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == ['fiber-align fuzzy-surface: error: /some/where.png: '
                                 'Permission denied']
