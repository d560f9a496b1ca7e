# SPDX-License-Identifier: Apache-2.0
"""
The catalogue's two backends, chosen by a URL: a SQLite file (stdlib) or PostgreSQL.

URLs (:func:`parse`): ``default`` (the SQLite file ``$ROS_HOME/fiber_align/catalog.db``,
``ROS_HOME`` defaulting to ``~/.ros``; its folder is created), ``none`` (no catalogue),
a path or ``sqlite:///path`` (that SQLite file; its folder must exist), and
``postgresql://user@host:port/db`` (psycopg 3, the ``records`` extra). :func:`connect`
opens a :class:`Backend` and brings its schema to :data:`~.schema.SCHEMA_VERSION`
(migrating an older catalogue, refusing a newer one). Every failure to reach or use the
catalogue is a :class:`~.schema.CatalogError` of one line; the writer spools on it.
"""

import os
from pathlib import Path
import re
import sqlite3

from fiber_align import __version__
from fiber_align.records import schema
from fiber_align.records.schema import CatalogError

#: The advisory lock that serialises schema changes on one PostgreSQL database.
SCHEMA_LOCK = 41041
#: The words of a catalogue URL that are not a location.
OFF = 'none'
DEFAULT = 'default'


def ros_home(environ=None):
    """Return ``$ROS_HOME`` (default ``~/.ros``) as a Path."""
    env = os.environ if environ is None else environ
    return Path(env.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros'))


def default_path(environ=None):
    """Return the default SQLite catalogue, ``$ROS_HOME/fiber_align/catalog.db``."""
    return ros_home(environ) / 'fiber_align' / 'catalog.db'


def redact(url):
    """Return ``url`` without its password (for log lines and errors)."""
    return re.sub(r'(://[^:/@]+):[^@/]*@', r'\1:***@', str(url))


def parse(url, environ=None):
    """
    Return ``(dialect, location)`` of a catalogue URL, or None for ``none``.

    ``dialect`` is ``sqlite`` (location: a Path) or ``postgresql`` (location: the URL).
    """
    url = str(url or '').strip()
    if url == '' or url.lower() == OFF:
        return None
    if url.lower() == DEFAULT:
        return 'sqlite', default_path(environ)
    if url.startswith(('postgresql://', 'postgres://')):
        return 'postgresql', url
    if url.startswith('sqlite://'):
        path = url[len('sqlite://'):]
        if not path:
            raise CatalogError('catalogue URL %r names no file (sqlite:///path/catalog.db)'
                               % url)
        return 'sqlite', Path(path)
    if '://' in url:
        raise CatalogError('catalogue URL %r: unknown scheme (use default, none, a path, '
                           'sqlite:///path or postgresql://...)' % redact(url))
    return 'sqlite', Path(url).expanduser()


def describe(url, environ=None):
    """Return the catalogue a URL names, for people (a path, or the URL without password)."""
    p = parse(url, environ)
    return 'none' if p is None else str(p[1]) if p[0] == 'sqlite' else redact(p[1])


def connect(url, environ=None, connect_timeout_s=2.0, busy_timeout_s=0.5, create=True):
    """
    Open the catalogue ``url``; return a :class:`Backend` with its schema current.

    :param connect_timeout_s: PostgreSQL connection attempt, s.
    :param busy_timeout_s: how long a SQLite statement waits on a lock, s.
    :param create: create the tables in an empty catalogue (the writer); the readers
        refuse a missing SQLite file instead.
    :raises CatalogError: one line: the catalogue cannot be reached, created or read.
    """
    p = parse(url, environ)
    if p is None:
        raise CatalogError('the catalogue is off (none)')
    dialect, where = p
    if dialect == 'sqlite':
        backend = SQLiteBackend(where, busy_timeout_s, create,
                                default=str(url).strip().lower() == DEFAULT)
    else:
        backend = PostgresBackend(where, connect_timeout_s)
    try:
        backend.ensure_schema()
    except CatalogError:
        backend.close()
        raise
    except Exception as exc:        # noqa: BLE001 - any driver error becomes one line
        backend.close()
        raise CatalogError('catalogue %s: %s' % (backend.name, one_line(exc))) from None
    return backend


def one_line(exc):
    """Return the first line of an exception's text (drivers write several)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__


class Backend:
    """
    One open catalogue: a connection, its dialect, the idempotent writes and the queries.

    Subclasses open the connection; this class holds what both dialects share (the SQL is
    one text, its placeholders ``?`` turned into ``%s`` for PostgreSQL).
    """

    dialect = None
    name = ''
    conn = None

    def sql(self, text):
        """Return ``text`` (written with ``?`` placeholders) in this dialect."""
        return text if self.dialect == 'sqlite' else text.replace('?', '%s')

    def execute(self, text, args=()):
        """Run one statement; return its cursor."""
        cur = self.conn.cursor()
        cur.execute(self.sql(text), tuple(args))
        return cur

    def query(self, text, args=()):
        """Return the rows of a query as a list of tuples, and the column names."""
        cur = self.execute(text, args)
        rows = cur.fetchall()
        cols = [d[0] for d in cur.description]
        cur.close()
        self.conn.commit()
        return rows, cols

    def version(self):
        """Return the catalogue's schema version, or None when it has no tables yet."""
        if not self.has_table(schema.VERSION_TABLE):
            return 0 if self.has_table('runs') else None
        rows, _ = self.query('SELECT MAX(version) FROM %s' % schema.VERSION_TABLE)
        return rows[0][0] if rows and rows[0][0] is not None else 0

    def ensure_schema(self):
        """Create, migrate or refuse (:func:`~.schema.check_version`) the catalogue."""
        found = self.version()
        if found is None:
            self.run_statements(schema.create_v1(self.dialect))
            found = 1
        schema.check_version(found, self.name)
        steps = schema.migrations(self.dialect)
        while found < schema.SCHEMA_VERSION:
            self.run_statements(steps[found] + [
                'UPDATE %s SET version = %d, package_version = %r'
                % (schema.VERSION_TABLE, found + 1, __version__)])
            found += 1

    def run_statements(self, statements):
        """Run ``statements`` in one transaction."""
        cur = self.conn.cursor()
        try:
            for s in statements:
                cur.execute(s)
            self.conn.commit()
        except Exception:
            self.conn.rollback()
            raise
        finally:
            cur.close()

    def write(self, rows):
        """
        Write ``rows`` (``(table, {column: value})``) in one transaction, idempotently.

        :raises Exception: the driver's error (the writer spools the rows on it).
        """
        cur = self.conn.cursor()
        try:
            for table, row in rows:
                cols = schema.names(table)
                cur.execute(schema.upsert(table, self.dialect),
                            tuple(self.to_db(table, row, cols)))
            self.conn.commit()
        except Exception:
            try:
                self.conn.rollback()
            except Exception:       # noqa: BLE001 - the connection may be gone already
                pass
            raise
        finally:
            try:
                cur.close()
            except Exception:       # noqa: BLE001
                pass

    def to_db(self, table, row, cols):
        """Return the values of ``row`` in column order, converted for this dialect."""
        kinds = schema.kinds(table)
        for c in cols:
            v = row.get(c)
            if v is not None and kinds[c] == 'bool':
                v = bool(v) if self.dialect == 'postgresql' else int(bool(v))
            yield v

    def close(self):
        """Close the connection (idempotent)."""
        if self.conn is not None:
            try:
                self.conn.close()
            except Exception:       # noqa: BLE001 - closing a dead connection
                pass
            self.conn = None


class SQLiteBackend(Backend):
    """A SQLite file (stdlib ``sqlite3``)."""

    dialect = 'sqlite'

    def __init__(self, path, busy_timeout_s, create=True, default=False):
        """Open ``path``; for the default catalogue create its folder first."""
        path = Path(path)
        self.name = str(path)
        folder = path.parent
        if default:
            try:
                folder.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise CatalogError('catalogue %s: cannot create folder %s (%s)'
                                   % (path, folder, exc.strerror or exc)) from None
        if not folder.is_dir():
            raise CatalogError('catalogue %s: folder %s does not exist' % (path, folder))
        if not create and not path.is_file():
            raise CatalogError('catalogue %s does not exist' % path)
        if not path.exists() and not os.access(folder, os.W_OK):
            raise CatalogError('catalogue %s: cannot write in folder %s (permission denied)'
                               % (path, folder))
        if path.exists() and not os.access(path, os.W_OK) and create:
            raise CatalogError('catalogue %s: not writable (permission denied)' % path)
        try:
            self.conn = sqlite3.connect(str(path), timeout=busy_timeout_s,
                                        check_same_thread=False)
        except sqlite3.Error as exc:
            raise CatalogError('catalogue %s: %s' % (path, one_line(exc))) from None

    def has_table(self, table):
        """Tell whether ``table`` exists."""
        rows, _ = self.query("SELECT name FROM sqlite_master WHERE type = 'table' AND "
                             'name = ?', (table,))
        return bool(rows)


class PostgresBackend(Backend):
    """A PostgreSQL database (psycopg 3)."""

    dialect = 'postgresql'

    def __init__(self, url, connect_timeout_s):
        """Connect to ``url`` within ``connect_timeout_s`` (s)."""
        self.name = redact(url)
        try:
            import psycopg
        except ImportError:
            raise CatalogError('catalogue %s: psycopg is not installed (pip install '
                               '"psycopg[binary]", the records extra)' % self.name) from None
        try:
            self.conn = psycopg.connect(url, connect_timeout=max(1, int(round(
                connect_timeout_s))))
        except Exception as exc:    # noqa: BLE001 - refused, unknown host, bad password
            raise CatalogError('catalogue %s: cannot connect: %s'
                               % (self.name, one_line(exc))) from None

    def ensure_schema(self):
        """Create or migrate the schema under a lock: two stations may start at once."""
        self.run_statements(['SELECT pg_advisory_lock(%d)' % SCHEMA_LOCK])
        try:
            super().ensure_schema()
        finally:
            self.run_statements(['SELECT pg_advisory_unlock(%d)' % SCHEMA_LOCK])

    def has_table(self, table):
        """Tell whether ``table`` exists (in the search path)."""
        rows, _ = self.query('SELECT to_regclass(?) IS NOT NULL', (table,))
        return bool(rows[0][0])
