# SPDX-License-Identifier: Apache-2.0
"""
A recording bag that survives a full disk: the tail is lost, not the bag (pure: no rclpy).

:class:`GuardedBag` wraps an opened rosbags ``Writer`` (mcap). A write that fails (``No
space left on device``, a quota, an I/O error) stops the recording: the chunk being
written is cut off the file again (the file ends at the last whole chunk), its messages
are taken off the counts, a reserve kept free beside the bag since its start
(:data:`RESERVE_BYTES`) is released and the bag is closed at once, with its summary and
``metadata.yaml``: readable as it is, without ``fiber-align bag-repair``. The caller gets
one line (:attr:`GuardedBag.stopped`) saying what failed and where, and records no more;
the graph it records runs on.

The mcap file is written through :class:`ExactFile` (one ``write(2)`` per chunk close,
every byte accounted for): a buffered file would keep the failed chunk's bytes and write
them on its close.
Other storages (sqlite3) are closed with the reserve released, without the cut.

A message goes into the mcap writer's pending chunk by :meth:`GuardedBag.write` itself,
the record packed at once (:data:`MESSAGE_RECORD`) with the writer's own bookkeeping
(chunk index, times, counts): the same bytes as the writer's ``write``, which builds
the record field by field and takes about 17 us a message here against 3 us, and a
recorder hosted on a control thread writes thousands a second
(``test/test_analysis_bag_guard.py`` compares the files).
"""

import errno
import json
import os
from pathlib import Path
import sqlite3
import struct

#: bytes kept allocated beside the bag (``.reserve`` in its directory) until it closes:
#: the close writes the mcap summary (each schema and channel, one index per chunk,
#: statistics) and ``metadata.yaml``, some kB for the graph's topics (a 5 MB bag of 20
#: topics: about 30 kB); a full disk has no byte left for them without it
RESERVE_BYTES = 256 * 1024
#: what a failed write is, by errno, for the one line
WHAT = {errno.ENOSPC: 'the disk is full', errno.EDQUOT: 'the disk quota is exceeded'}
#: what a failed write raises (sqlite3: "database or disk is full")
FAILED = (OSError, sqlite3.Error)
#: an mcap Message record's head: opcode 0x05, record length, channel id, sequence (0,
#: as rosbags), log time and publish time (ns); the CDR bytes follow
MESSAGE_RECORD = struct.Struct('<BQHIQQ')
#: the record's length before the data (channel id, sequence, two times)
_MESSAGE_FIELDS = 22
#: a pending chunk past this many bytes is closed (rosbags' own limit)
CHUNK_BYTES = 2 ** 20


def mount_point(path):
    """Return the mount point of the filesystem holding ``path``."""
    p = os.path.abspath(path)
    while not os.path.ismount(p):
        p = os.path.dirname(p)
    return p


class ExactFile:
    """
    The mcap writer's file: writes gathered in memory, then one ``write(2)`` per flush.

    rosbags writes each record in three pieces (opcode, length, body), so a chunk close
    of twenty topics made some sixty system calls on the control thread, each releasing
    the GIL to whichever thread wanted it; gathered, a close is one call. A flush writes
    every byte or raises :class:`OSError` (nothing is kept for a later close to write).

    :param path: the file (it exists); writing continues at ``pos`` (bytes).
    """

    def __init__(self, path, pos):
        """Open ``path`` for writing at ``pos`` (bytes)."""
        self.f = open(path, 'r+b', buffering=0)
        self.f.seek(pos)
        self.pos = pos
        self.buf = bytearray()

    def write(self, data):
        """Take ``data`` for the next :meth:`flush`; return its length (bytes)."""
        self.buf += data
        n = len(data) if isinstance(data, (bytes, bytearray)) else memoryview(data).nbytes
        self.pos += n
        return n

    def flush(self):
        """Write every gathered byte to the file or raise :class:`OSError`."""
        view = memoryview(self.buf)
        done = 0
        try:
            while done < len(view):
                n = self.f.write(view[done:])
                if not n:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                done += n
        finally:
            view.release()
            del self.buf[:done]

    def tell(self):
        """Return the position (bytes), the gathered bytes included."""
        return self.pos

    def truncate(self, pos):
        """Cut the file at ``pos`` (bytes), drop what is gathered, write on from there."""
        self.buf.clear()
        self.f.truncate(pos)
        self.f.seek(pos)
        self.pos = pos

    def close(self):
        """Write what is gathered, then close the file (closed even when the write fails)."""
        try:
            self.flush()
        finally:
            self.buf.clear()
            self.f.close()


def write_json(directory, files):
    """
    Write ``{name: data}`` as JSON files into ``directory``; return None or why not.

    The recorder's counts beside its bag: after a full disk they may not fit (one line).
    """
    try:
        for name, data in files.items():
            with open(os.path.join(str(directory), name), 'w', encoding='utf-8') as f:
                json.dump(data, f, indent=1, sort_keys=True)
    except OSError as exc:
        return str(exc)
    return None


def _chunk_times(index):
    """Return ``(start, end)`` (ns) of a chunk index record (its first two fields)."""
    return struct.unpack_from('<QQ', index.getbuffer())


class GuardedBag:
    """
    An opened rosbags ``Writer`` whose failed write closes the bag readable (see module).

    :param writer: the opened writer (``Writer.open()`` done, nothing written yet).
    :param reserve_bytes: bytes kept free for the close (:data:`RESERVE_BYTES`).
    """

    def __init__(self, writer, reserve_bytes=RESERVE_BYTES):
        """Allocate the reserve; write the mcap file through :class:`ExactFile`."""
        self.writer = writer
        self.path = Path(writer.path)
        self.stopped = None             # the one line, once a write failed
        self.closed = False
        self.reserve = self.path / '.reserve'
        with open(self.reserve, 'wb') as f:
            try:
                os.posix_fallocate(f.fileno(), 0, int(reserve_bytes))
            except OSError:             # a filesystem without fallocate: real zeros
                f.write(bytes(int(reserve_bytes)))
        storage = writer.storage
        self.mcap = hasattr(storage, 'close_chunk') and hasattr(storage, 'bio')
        if self.mcap:
            storage.bio.flush()
            exact = ExactFile(storage.path, storage.bio.tell())
            storage.bio.close()
            storage.bio = exact
            self._close_chunk = storage.close_chunk
            storage.close_chunk = self._guarded_close_chunk
        # packed here unless the writer compresses each message (its own write then)
        self._pack = self.mcap and writer.compression_mode.name != 'MESSAGE'

    # -- writing ----------------------------------------------------------------------
    def add_connection(self, *args, **kwargs):
        """Add a connection (the writer's); no file write happens here."""
        return self.writer.add_connection(*args, **kwargs)

    def write(self, conn, t_ns, data):
        """Write one message (ns, CDR bytes); return False once recording has stopped."""
        if self.stopped or self.closed:
            return False
        try:
            if self._pack:
                self._write_mcap(conn, t_ns, data)
            else:
                self.writer.write(conn, t_ns, data)
        except FAILED as exc:
            self._stop(exc)
            return False
        return True

    def _write_mcap(self, conn, t_ns, data):
        """Append one Message record to the pending chunk, as the writer's ``write`` does."""
        w = self.writer
        st, cid = w.storage, conn.id
        ch = st.chunk
        bio = ch.bio
        if t_ns < ch.message_start_time:
            ch.message_start_time = t_ns
        if t_ns > ch.message_end_time:
            ch.message_end_time = t_ns
        if t_ns < st.message_start_time:
            st.message_start_time = t_ns
        if t_ns > st.message_end_time:
            st.message_end_time = t_ns
        if t_ns < w.min_timestamp:
            w.min_timestamp = t_ns
        if t_ns > w.max_timestamp:
            w.max_timestamp = t_ns
        ch.msgs[cid].append((t_ns, bio.tell()))
        bio.write(MESSAGE_RECORD.pack(5, _MESSAGE_FIELDS + len(data), cid, 0, t_ns, t_ns))
        bio.write(data)
        st.channel_stats[cid] += 1
        w.counts[cid] += 1
        if bio.tell() > CHUNK_BYTES:
            st.close_chunk()

    def flush(self):
        """Write the pending chunk to the file; return False once recording has stopped."""
        if self.stopped or self.closed:
            return False
        storage = self.writer.storage
        try:
            if self.mcap and storage.chunk.bio.tell():
                storage.close_chunk()
        except OSError as exc:
            self._stop(exc)
            return False
        return True

    def _guarded_close_chunk(self):
        """Run the writer's ``close_chunk``; a failure cuts the chunk off again (and raises)."""
        storage = self.writer.storage
        start, n, lost = storage.bio.tell(), len(storage.chunks), storage.chunk
        try:
            self._close_chunk()
            storage.bio.flush()
        except OSError:
            storage.bio.truncate(start)
            del storage.chunks[n:]
            self._forget(storage, lost)
            raise

    def _forget(self, storage, lost):
        """Take the ``lost`` chunk's messages off the counts and the times; start a new one."""
        for cid, msgs in lost.msgs.items():
            storage.channel_stats[cid] -= len(msgs)
        # the storage counted the message whose write failed, the writer not yet
        self.writer.counts.update(storage.channel_stats)
        times = [_chunk_times(c) for c in storage.chunks]
        start = min((t[0] for t in times), default=2 ** 63 - 1)
        end = max((t[1] for t in times), default=0)
        storage.message_start_time = self.writer.min_timestamp = start
        storage.message_end_time = self.writer.max_timestamp = end
        storage.chunk = type(lost)(2 ** 63 - 1, 0, type(lost.bio)(), type(lost.msgs)(list))

    def counts(self):
        """Return ``{topic: messages in the bag}`` (a cut chunk's no longer counted)."""
        out = {}
        for c in self.writer.connections:
            out[c.topic] = out.get(c.topic, 0) + self.writer.counts.get(c.id, 0)
        return out

    # -- the stop ---------------------------------------------------------------------
    def _stop(self, exc):
        """
        Stop recording after ``exc``: release the reserve, say so in one line.

        The caller closes the bag (:meth:`close`: its summary and ``metadata.yaml`` in the
        released reserve) where it has the time: a composed process off its control thread.
        """
        what = WHAT.get(getattr(exc, 'errno', None)) or (
            'the disk is full' if 'full' in str(exc) else 'a write failed')
        self._release()
        self.stopped = (
            'recording stopped early: %s at %s (filesystem %s: %s); the bag keeps the %d '
            'message(s) before it and is closed readable' % (
                what, self.path, mount_point(self.path), getattr(exc, 'strerror', '') or exc,
                sum(self.writer.counts.values())))

    def _release(self):
        """Free the reserve (once)."""
        try:
            os.unlink(self.reserve)
        except OSError:
            pass

    def close(self):
        """Close the bag (idempotent): release the reserve first; return None or why not."""
        if self.closed:
            return None
        self.closed = True
        self._release()
        why = None
        for _ in range(2):      # a pending chunk that failed is cut off: then the summary
            try:
                self.writer.close()
                return None
            except FAILED as exc:
                why = str(exc)
        return why
