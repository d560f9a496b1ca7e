# SPDX-License-Identifier: Apache-2.0
"""
The catalogue's writer: rows in, never a wait for its caller, none lost, none twice.

The caller (a node's callback, the offline CLI) calls :meth:`CatalogWriter.put`, which
only puts the row into a bounded queue (``queue_size``); a thread of the writer takes
the rows out and writes them in one transaction per batch. When the catalogue is locked,
full or unreachable (any error of the driver, or :class:`~.schema.CatalogError` on
connecting), the rows go to a spool file (JSON lines, ``spool_dir``) in their order, and
every row after them goes there too until the spool is written: the writer tries the
catalogue again every ``retry_period_s`` (s), writes the spool's rows, then empties it.
The writes are idempotent (:func:`~.schema.upsert`): a spool replayed after a commit
whose acknowledgement was lost changes nothing. A spool left by a stopped writer is
written by the next writer of the same catalogue. :meth:`state` says ``ok``, ``spooling``
(with the reason: the line for ``/diagnostics``) or ``off`` (URL ``none``).
"""

import contextlib
import fcntl
import hashlib
import json
from pathlib import Path
import queue
import threading
import time

from fiber_align.jsonout import json_clean
from fiber_align.records import backends
from fiber_align.records.schema import CatalogError, TABLES

#: Rows written in one transaction at most.
BATCH = 1000
_STOP = object()


def spool_path(url, spool_dir='', environ=None):
    """Return the spool file of catalogue ``url`` (one per catalogue, named by its hash)."""
    folder = Path(spool_dir) if spool_dir else backends.ros_home(environ) / 'fiber_align' / \
        'spool'
    key = hashlib.sha1(str(url).encode('utf-8')).hexdigest()[:16]
    return folder / ('catalog-%s.jsonl' % key)


class CatalogWriter:
    """
    Write rows of the catalogue ``url`` from a thread of its own (see the module docstring).

    :param url: a catalogue URL (:func:`~.backends.parse`); ``none`` turns it off.
    :param params: the ``run_catalog`` section of ``config/records.yaml``
        (``queue_size``, ``retry_period_s`` s, ``connect_timeout_s`` s, ``busy_timeout_s``
        s, ``spool_dir``).
    :param connect: the backend factory (tests swap it); ``environ``: for ``ROS_HOME``.
    """

    def __init__(self, url, params, environ=None, connect=backends.connect):
        """Check the URL, then start the writer thread (none for ``none``)."""
        self.url = str(url)
        self.off = backends.parse(self.url, environ) is None
        self.name = backends.describe(self.url, environ)
        self.retry_period_s = float(params['retry_period_s'])
        self._connect_kw = dict(environ=environ, connect_timeout_s=params['connect_timeout_s'],
                                busy_timeout_s=params['busy_timeout_s'])
        self._connect = connect
        self.spool = spool_path(self.url, params['spool_dir'], environ)
        self._queue = queue.Queue(maxsize=int(params['queue_size']))
        self._lock = threading.Lock()
        self._held = []             # rows that wait when even the spool cannot be written
        self._spooled = 0
        self._counts = dict(written=0, dropped=0)
        self._reason = ''
        self._refused_at = -float('inf')    # monotonic s of the last failed try
        self._db = None
        self._last_try = -float('inf')
        self._idle = threading.Event()
        self._thread = None
        if self.off:
            return
        self._spooled = self._count_spool()
        self._thread = threading.Thread(target=self._run, name='catalog-writer', daemon=True)
        self._thread.start()

    # --- the caller's side: never waits ---
    def put(self, table, row):
        """Queue one row of ``table`` (``runs`` or ``alignments``); return at once."""
        if table not in TABLES:
            raise ValueError('unknown catalogue table %r' % table)
        if self.off:
            return False
        self._idle.clear()
        try:
            self._queue.put_nowait((table, json_clean(dict(row))))
            return True
        except queue.Full:
            with self._lock:
                self._counts['dropped'] += 1
                self._reason = 'queue full (%d rows): rows dropped' % self._queue.maxsize
            return False

    def state(self):
        """
        Return ``{'level', 'reason', 'queued', 'spooled', 'written', 'dropped'}``.

        ``level``: ``ok`` (rows reach the catalogue), ``spooling`` (they wait; ``reason``
        says why) or ``off``.
        """
        with self._lock:
            spooling = bool(self._spooled or self._held or self._reason)
            level = 'off' if self.off else 'spooling' if spooling else 'ok'
            return dict(level=level, reason=self._reason if spooling else '',
                        queued=self._queue.qsize(), spooled=self._spooled + len(self._held),
                        **self._counts)

    def flush(self, timeout_s, until_refused=False):
        """
        Wait up to ``timeout_s`` (s) until every row is written; tell whether it is.

        ``until_refused``: also stop waiting once every row is out of the queue (written
        or in the spool) and a try of the catalogue made during this wait failed: a
        missing folder or a refused login will not heal in the next seconds, and the
        rows wait safely in the spool for the next writer.
        """
        if self.off:
            return True
        start = time.monotonic()
        t_end = start + timeout_s
        while time.monotonic() < t_end:
            s = self.state()
            if s['level'] == 'ok' and s['queued'] == 0 and self._idle.is_set():
                return True
            with self._lock:
                refused = self._refused_at > start
            if until_refused and refused and s['queued'] == 0 and not self._held:
                return False
            time.sleep(0.02)
        return False

    def close(self, timeout_s=5.0):
        """Write what it can within ``timeout_s`` (s), stop the thread; return :meth:`state`."""
        if self._thread is not None:
            self._queue.put(_STOP)      # may wait for a slot: only at the very end
            self._thread.join(timeout_s)
            self._thread = None
        return self.state()

    # --- the writer thread ---
    def _run(self):
        self._retry(force=True)         # connect, and write a spool an earlier writer left
        stopping = False
        while True:
            batch = []
            try:
                batch.append(self._queue.get(timeout=min(0.1, self.retry_period_s)))
                while len(batch) < BATCH:
                    batch.append(self._queue.get_nowait())
            except queue.Empty:
                pass
            if any(x is _STOP for x in batch):
                stopping = True
            rows = [x for x in batch if x is not _STOP]
            if self._spooled or self._held or self._db is None:
                self._to_spool(rows)
                self._retry(force=stopping)
            elif rows:
                self._write(rows)
            if not batch and not self._spooled and not self._held and self._queue.empty():
                self._idle.set()
            if stopping:
                if self._db is not None:
                    self._db.close()
                return

    def _retry(self, force=False):
        """Connect and write the spool, at most every ``retry_period_s``."""
        now = time.monotonic()
        if not force and now - self._last_try < self.retry_period_s:
            return
        self._last_try = now
        if self._db is None:
            try:
                self._db = self._connect(self.url, **self._connect_kw)
            except CatalogError as exc:
                self._set_reason(str(exc))
                return
        with self._spool_lock():
            try:
                rows = self._read_spool() + list(self._held)
                for i in range(0, len(rows), BATCH):
                    self._db.write(rows[i:i + BATCH])
            except Exception as exc:    # noqa: BLE001 - locked, full, gone: spool on
                self._lost(exc)
                return
            self._clear_spool()
        with self._lock:
            self._counts['written'] += len(rows)
            self._held = []
            self._spooled = 0
            self._reason = ''

    def _write(self, rows):
        try:
            self._db.write(rows)
        except Exception as exc:    # noqa: BLE001 - locked, full, gone: spool them
            self._lost(exc)
            self._to_spool(rows)
            return
        with self._lock:
            self._counts['written'] += len(rows)

    def _lost(self, exc):
        self._set_reason('catalogue %s: %s' % (self.name, backends.one_line(exc)))
        if self._db is not None:
            self._db.close()
        self._db = None
        self._last_try = time.monotonic()

    def _set_reason(self, text):
        with self._lock:
            self._reason = text
            self._refused_at = time.monotonic()

    # --- the spool file ---
    def _to_spool(self, rows):
        if not rows:
            return
        lines = ''.join(json.dumps({'table': t, 'row': r}, sort_keys=True) + '\n'
                        for t, r in rows)
        try:
            self.spool.parent.mkdir(parents=True, exist_ok=True)
            with self._spool_lock(), open(self.spool, 'a', encoding='utf-8') as f:
                f.write(lines)
                f.flush()
            with self._lock:
                self._spooled += len(rows)
        except OSError as exc:
            with self._lock:
                room = self._queue.maxsize - len(self._held)
                self._held.extend(rows[:max(0, room)])
                self._counts['dropped'] += max(0, len(rows) - max(0, room))
                if not self._reason:
                    self._reason = 'spool %s: %s' % (self.spool, exc.strerror or exc)

    @contextlib.contextmanager
    def _spool_lock(self):
        """Hold the spool's lock file: two writers of one catalogue share its spool."""
        try:
            self.spool.parent.mkdir(parents=True, exist_ok=True)
            f = open(str(self.spool) + '.lock', 'a')
        except OSError:
            yield           # no folder for a lock: no spool to share either
            return
        try:
            fcntl.flock(f, fcntl.LOCK_EX)
            yield
        finally:
            f.close()       # closing releases the lock

    def _count_spool(self):
        try:
            with open(self.spool, encoding='utf-8') as f:
                return sum(1 for line in f if line.strip())
        except OSError:
            return 0

    def _read_spool(self):
        try:
            with open(self.spool, encoding='utf-8') as f:
                text = f.read()
        except FileNotFoundError:
            return []
        rows = []
        for line in text.splitlines():
            if not line.strip():
                continue
            try:
                d = json.loads(line)
            except ValueError:      # a line cut by a crash mid-write: its row was queued
                continue            # again by nobody, so it is the only loss possible
            rows.append((d['table'], d['row']))
        return rows

    def _clear_spool(self):
        try:
            self.spool.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            self._set_reason('spool %s: %s' % (self.spool, exc.strerror or exc))
