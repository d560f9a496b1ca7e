# SPDX-License-Identifier: Apache-2.0
"""
A PostgreSQL server of the tests' own: ``initdb`` and ``pg_ctl`` in a temporary folder.

The server listens on 127.0.0.1 on a free port, its unix socket in the same temporary
folder, with trust authentication for the user ``postgres`` (nobody else can reach a
loopback port of a test machine's session, and the folder is removed after). As root,
``initdb`` refuses to run: the server then runs as the unprivileged user ``nobody``
(``setpriv``), which owns the folder. Every start and stop is bounded; :meth:`remove`
stops it (``fast``, then SIGKILL of the postmaster) and removes the folder, also after
a failed test (the session fixture's ``finally``).
"""

import glob
import importlib.util
import os
from pathlib import Path
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time

#: Where the Debian server packages put the binaries (newest first); without them, ``pg_ctl``
#: on the PATH, then the pip package ``pgserver``'s (the test extra) binaries.
BIN_GLOBS = ('/usr/lib/postgresql/*/bin',)
USER = 'nobody'


def find_bindir():
    """Return the folder holding ``initdb`` and ``pg_ctl``, or None."""
    env = os.environ.get('FIBER_ALIGN_PG_BINDIR')
    candidates = [env] if env else []
    for pattern in BIN_GLOBS:
        candidates += sorted(glob.glob(pattern), key=lambda p: [
            int(x) if x.isdigit() else 0 for x in Path(p).parent.name.split('.')], reverse=True)
    for c in candidates:
        if c and os.path.isfile(os.path.join(c, 'initdb')) and \
                os.path.isfile(os.path.join(c, 'pg_ctl')):
            return c
    on_path = shutil.which('pg_ctl')
    if on_path:
        return os.path.dirname(os.path.realpath(on_path))
    # a machine without a server package: the pip-installed one (the test extra's pgserver)
    spec = importlib.util.find_spec('pgserver')
    if spec is not None and spec.origin:
        bindir = Path(spec.origin).parent / 'pginstall' / 'bin'
        if (bindir / 'initdb').is_file():
            return str(bindir)
    return None


def free_port():
    """Return a TCP port on 127.0.0.1 that nobody listens on now."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class PgServer:
    """One PostgreSQL cluster in a temporary folder (see the module docstring)."""

    def __init__(self, bindir, timeout_s=60.0):
        """Create the cluster (``initdb``); not started yet."""
        self.bindir = bindir
        self.timeout_s = timeout_s
        self.as_root = os.geteuid() == 0
        # the server's user must reach its folder: under root, in /tmp (world-traversable)
        self.root = Path(tempfile.mkdtemp(prefix='fa_pg_', dir='/tmp' if self.as_root
                                          else None))
        self.data = self.root / 'data'
        self.log = self.root / 'server.log'
        self.port = free_port()
        if self.as_root:
            pw = pwd.getpwnam(USER)
            os.chown(self.root, pw.pw_uid, pw.pw_gid)
        self._run(['initdb', '-D', str(self.data), '-U', 'postgres', '--auth=trust',
                   '--encoding=UTF8', '--locale=C', '--no-sync'])

    @property
    def url(self):
        """Return the URL of the maintenance database ``postgres``."""
        return 'postgresql://postgres@127.0.0.1:%d/postgres' % self.port

    def url_of(self, dbname):
        """Return the URL of database ``dbname`` on this server."""
        return 'postgresql://postgres@127.0.0.1:%d/%s' % (self.port, dbname)

    def _cmd(self, args):
        exe = [os.path.join(self.bindir, args[0])] + list(args[1:])
        if self.as_root:
            return ['setpriv', '--reuid=%s' % USER, '--regid=nogroup', '--clear-groups',
                    '--'] + exe
        return exe

    def _run(self, args, nice=False):
        # the server runs niced: on a test machine it shares the realtime graph's two
        # cores, where a server elsewhere would not (its crash recovery at a restart
        # preempted the graph's Python threads, which hold the interpreter's lock)
        cmd = (['nice', '-n', '19'] if nice else []) + self._cmd(args)
        proc = subprocess.run(cmd, capture_output=True, text=True,
                              timeout=self.timeout_s, cwd=str(self.root),
                              env=dict(os.environ, LC_ALL='C'))
        if proc.returncode != 0:
            raise RuntimeError('%s failed (%d): %s %s' % (args[0], proc.returncode,
                                                          proc.stdout[-2000:],
                                                          proc.stderr[-2000:]))
        return proc

    def start(self):
        """Start the server and wait (bounded) until it takes connections."""
        opts = '-p %d -k %s -c listen_addresses=127.0.0.1 -c fsync=off' % (
            self.port, self.root)
        self._run(['pg_ctl', '-D', str(self.data), '-o', opts, '-l', str(self.log), '-w',
                   '-t', str(int(self.timeout_s)), 'start'], nice=True)

    def stop(self, mode='fast'):
        """Stop the server (``pg_ctl stop -m mode``), bounded."""
        self._run(['pg_ctl', '-D', str(self.data), '-m', mode, '-w', '-t',
                   str(int(self.timeout_s)), 'stop'])

    def running(self):
        """Tell whether the postmaster's pid file names a live process."""
        pid = self._pid()
        if pid is None:
            return False
        try:
            os.kill(pid, 0)
        except OSError:
            return False
        return True

    def _pid(self):
        try:
            return int((self.data / 'postmaster.pid').read_text().split('\n', 1)[0])
        except (OSError, ValueError):
            return None

    def create_database(self, name):
        """Create database ``name``; return its URL."""
        import psycopg
        with psycopg.connect(self.url, autocommit=True, connect_timeout=10) as conn:
            conn.execute('CREATE DATABASE %s' % name)
        return self.url_of(name)

    def remove(self):
        """Stop the server whatever its state, then remove its folder."""
        try:
            if self.running():
                try:
                    self.stop('fast')
                except Exception:       # noqa: BLE001 - then by signal
                    pid = self._pid()
                    if pid:
                        os.kill(pid, signal.SIGKILL)
                        t_end = time.monotonic() + 10.0
                        while self.running() and time.monotonic() < t_end:
                            time.sleep(0.1)
        finally:
            shutil.rmtree(self.root, ignore_errors=True)
