# SPDX-License-Identifier: Apache-2.0
"""
The path arguments of the ``fiber-align`` sub-commands, checked before a command runs.

A sub-command declares its path arguments in its parser's defaults,
``paths={'--plots': 'out-dir', 'BAG': 'in-any'}`` (the name as the usage shows it: an
option, or a positional in capitals), with one of these kinds:

* ``in-file``: an existing file to read;
* ``in-config``: an existing file, or a name the command resolves itself (a config in
  ``config/``, a keyword): a path that does not exist is left to the command;
* ``in-dir``: an existing folder;
* ``in-any``: an existing file or folder (a bag directory or its ``.mcap``, a CSV);
* ``out-file``: a file to write: not a folder, in an existing, writable folder;
* ``out-dir``: a folder to write into: an existing, writable folder, or a new one in an
  existing, writable folder;
* ``new-dir``: a folder to create: it must not exist, its parent folder must.

A bad path raises :class:`~fiber_align.tools.common.UsageError` with one line naming
the argument, the path and what is wrong; ``fiber-align`` exits 2 with it. Writability
is probed with an anonymous temporary file, so a folder that refuses writes (read-only,
``/proc``, ``/sys``) is caught before the command's work, whoever runs it.
"""

import errno
import os
from pathlib import Path
import tempfile

from fiber_align.tools.common import UsageError

KINDS = ('in-file', 'in-config', 'in-dir', 'in-any', 'out-file', 'out-dir', 'new-dir')


def dest(name):
    """Return the argparse ``dest`` of an argument name (``--link-dir`` -> ``link_dir``)."""
    return name.lstrip('-').replace('-', '_').lower()


def _writable(folder):
    """Return None if a file can be created in ``folder``, else the reason (text)."""
    try:
        with tempfile.TemporaryFile(dir=str(folder)):
            pass
    except OSError as exc:
        if exc.errno in (errno.ENOENT, errno.EOPNOTSUPP, errno.EISDIR):
            return 'it takes no new files'     # e.g. /proc, whatever the permissions
        return exc.strerror or str(exc)
    return None


def _parent(name, p):
    """Check that the folder an output goes into exists, is a folder and takes files."""
    parent = p.parent if str(p.parent) else Path('.')
    if not parent.exists():
        # a file on the way up makes the parent "missing" too: name that file
        up = parent
        while not up.exists() and up != up.parent:
            up = up.parent
        if up.exists() and not up.is_dir():
            raise UsageError('%s %s: %s is a file, not a folder' % (name, p, up))
        raise UsageError('%s %s: folder %s does not exist' % (name, p, parent))
    if not parent.is_dir():
        raise UsageError('%s %s: %s is a file, not a folder' % (name, p, parent))
    why = _writable(parent)
    if why:
        raise UsageError('%s %s: cannot write in folder %s (%s)' % (name, p, parent, why))


def check_path(name, value, kind):
    """
    Check one path argument; raise UsageError (one line) when it cannot be used.

    :param name: the argument as the usage shows it (``--plots``, ``BAG``).
    :param value: the path given (str); :param kind: one of :data:`KINDS`.
    """
    if kind not in KINDS:
        raise ValueError('unknown path kind %r (known: %s)' % (kind, ', '.join(KINDS)))
    p = Path(value)
    if kind.startswith('in-'):
        if not p.exists():
            if kind == 'in-config':
                return      # a name the command resolves, or a keyword; it says if not
            raise UsageError('%s %s: does not exist' % (name, value))
        if kind in ('in-file', 'in-config') and p.is_dir():
            raise UsageError('%s %s: is a folder, a file is wanted' % (name, value))
        if kind == 'in-dir' and not p.is_dir():
            raise UsageError('%s %s: is a file, a folder is wanted' % (name, value))
        if not os.access(str(p), os.R_OK):
            raise UsageError('%s %s: not readable (permission denied)' % (name, value))
        return
    if kind == 'out-file':
        if p.is_dir():
            raise UsageError('%s %s: is a folder, a file is wanted' % (name, value))
        _parent(name, p)
        return
    if p.exists():
        if kind == 'new-dir':
            raise UsageError('%s %s: exists already, a new folder is wanted' % (name, value))
        if not p.is_dir():
            raise UsageError('%s %s: is a file, a folder is wanted' % (name, value))
        why = _writable(p)
        if why:
            raise UsageError('%s %s: cannot write in this folder (%s)' % (name, value, why))
        return
    _parent(name, p)


def check_args(args):
    """Check every path argument ``args.paths`` declares and the user gave (not None)."""
    for name, kind in sorted(getattr(args, 'paths', {}).items()):
        value = getattr(args, dest(name), None)
        if value is not None:
            check_path(name, str(value), kind)


def os_error_line(exc):
    """Return one line for an OSError a command met (the file and the system's reason)."""
    what = exc.strerror or exc.__class__.__name__
    if exc.filename:
        return '%s: %s' % (exc.filename, what)
    return str(exc) or what
