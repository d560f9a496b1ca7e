# SPDX-License-Identifier: Apache-2.0
"""
Read the graph's rosbag2 bags (mcap and sqlite3) with rosbags, one topic at a time.

Streams the raw CDR bytes of a topic in chunks and decodes them
(:mod:`fiber_align.analysis.bag.decode`), so memory is bounded by the decoded arrays
plus one chunk of raw bytes. Times int64 ns, values SI.
"""

import itertools
from pathlib import Path
import struct

import numpy as np

from fiber_align.analysis.bag.common import _BATCH, BagError, discover, GRAPH_TOPICS
from fiber_align.analysis.bag.decode import _decode
from fiber_align.analysis.report import align_to_samples


def _open_reader(path):
    from rosbags.rosbag2 import Reader
    p = Path(path)
    if not p.exists():
        raise BagError('bag %s does not exist' % p)
    try:
        reader = Reader(p)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - every rosbags failure becomes one clear line
        raise BagError('cannot read bag %s: %s (truncated, corrupt or not a rosbag2 bag?)'
                       % (p, str(exc).strip() or type(exc).__name__)) from None
    return reader


class BagReader:
    """Open a rosbag2 bag and read graph streams from it (use as a context manager)."""

    def __init__(self, path):
        """Open the bag at ``path`` (directory, .mcap or .db3); raise :class:`BagError`."""
        self.path = Path(path)
        self.reader = _open_reader(path)
        try:
            self.topics = discover(self.reader.connections)
        except Exception:
            self.reader.close()
            raise

    def __enter__(self):
        """Return self."""
        return self

    def __exit__(self, *exc):
        """Close the bag."""
        self.close()

    def close(self):
        """Close the bag."""
        if self.reader is not None:
            self.reader.close()
            self.reader = None

    @property
    def all_topics(self):
        """Return {topic: (msgtype, count)} of every connection in the bag."""
        return {c.topic: (c.msgtype, c.msgcount) for c in self.reader.connections}

    def is_lockstep(self):
        """Return True when the bag holds ``/clock`` messages (simulated-time lockstep run)."""
        c = self.topics.get('clock')
        return c is not None and c.msgcount > 0

    def read(self, key, keep=None, stride=1):
        """
        Decode the stream ``key`` (a :data:`GRAPH_TOPICS` key) into a :class:`Stream`.

        :param keep: field names to keep (default all), to save memory.
        :param stride: keep every ``stride``-th message only (for plots of long runs).
        :returns: the stream, or ``None`` if the bag has no such topic.
        :raises BagError: the bag's data is truncated or corrupt.
        """
        conn = self.topics.get(key)
        if conn is None:
            return None
        try:
            return _decode(self, conn, keep, stride)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - clear one-line error for corrupt data
            raise BagError('cannot read %s from bag %s: %s (truncated or corrupt?)'
                           % (conn.topic, self.path, str(exc).strip() or type(exc).__name__)
                           ) from None

    # ----- raw access

    def raw_batches(self, conn, batch=_BATCH):
        """
        Yield (t_ns int64 array, rows) batches of one connection's raw CDR messages.

        ``rows`` is an (n, L) uint8 array when every message of the batch has the same
        length, else a list of ``bytes``. Messages come in bag order (timestamp order).
        """
        storages = _storages(self.reader)
        if storages is None:
            yield from _generic_batches(self.reader, conn, batch)
            return
        for st in storages:
            sconn = next((c for c in st.connections
                          if c.topic == conn.topic and c.msgtype == conn.msgtype), None)
            if sconn is None:
                continue
            kind = type(st).__name__
            if kind == 'McapReader' and getattr(st, 'chunks', None):
                yield from _mcap_batches(st, sconn)
            elif kind == 'Sqlite3Reader' and getattr(st, 'dbconn', None) is not None:
                yield from _sqlite_batches(st, sconn, batch)
            else:
                yield from _generic_batches(st, sconn, batch)


def _storages(reader):
    """
    Return the storage readers (rosbags internals) of ``reader`` in file order, or None.

    None means "use the public per-message API": unknown internals or per-message
    compression.
    """
    top = getattr(reader, 'storage', None)
    kind = type(top).__name__
    if kind in ('McapReader', 'Sqlite3Reader'):
        return [top]
    if kind != 'DirectoryReader':
        return None
    meta = getattr(top, 'metadata', None)
    if getattr(meta, 'compression_mode', None) == 'message':
        return None
    sts = getattr(top, 'storages', None)
    return list(sts) if sts else None


def _rows(datas):
    """Return an (n, L) uint8 array if all ``datas`` share a length, else the list."""
    if not datas:
        return np.zeros((0, 0), np.uint8)
    n0 = len(datas[0])
    if all(len(d) == n0 for d in datas):
        return np.frombuffer(b''.join(datas), np.uint8).reshape(len(datas), n0)
    return list(datas)


def _generic_batches(reader, conn, batch):
    """Yield batches through the per-message ``messages()`` API of a reader or storage."""
    ts, ds = [], []
    for _, t, data in reader.messages([conn]):
        ts.append(t)
        ds.append(bytes(data))
        if len(ts) >= batch:
            yield np.asarray(ts, np.int64), _rows(ds)
            ts, ds = [], []
    if ts:
        yield np.asarray(ts, np.int64), _rows(ds)


def _sqlite_batches(storage, conn, batch):
    """Yield batches straight from the sqlite3 database of a rosbags Sqlite3Reader."""
    cur = storage.dbconn.execute('SELECT timestamp, data FROM messages WHERE topic_id=? '
                                 'ORDER BY timestamp, id', (conn.id,))
    while True:
        rows = list(itertools.islice(cur, batch))
        if not rows:
            break
        ts = np.fromiter((r[0] for r in rows), np.int64, len(rows))
        yield ts, _rows([r[1] for r in rows])


def _mcap_batches(storage, conn):
    """
    Yield one batch per MCAP chunk using the chunk and message indexes (no per-message Python).

    For each chunk holding the channel, the chunk is decompressed (rosbags' own
    decompressor and CRC check), the channel's message index gives the (log time,
    offset) pairs, and the message bodies are gathered with numpy.
    """
    from rosbags.rosbag2.storage_mcap import decompress
    bio = storage.bio
    cid = conn.id
    chunks = sorted((c for c in storage.chunks if cid in c.message_index_offsets),
                    key=lambda c: (c.message_start_time, c.chunk_start_offset))
    for ch in chunks:
        bio.seek(ch.chunk_start_offset)
        head = bio.read(9 + 28)
        if len(head) < 37 or head[0] != 0x06:
            raise BagError('chunk at byte %d is not a chunk record' % ch.chunk_start_offset)
        crc = struct.unpack_from('<I', head, 9 + 24)[0]
        (clen,) = struct.unpack('<I', bio.read(4))
        comp = bio.read(clen).decode()
        (csize,) = struct.unpack('<Q', bio.read(8))
        data = bio.read(csize)
        if len(data) != csize:
            raise BagError('chunk at byte %d is truncated' % ch.chunk_start_offset)
        raw = decompress(data, comp, ch.uncompressed_size, crc)
        bio.seek(ch.message_index_offsets[cid])
        ih = bio.read(1 + 8 + 2 + 4)
        if len(ih) < 15 or ih[0] != 0x07:
            raise BagError('message index at byte %d is invalid' % ch.message_index_offsets[cid])
        alen = struct.unpack_from('<I', ih, 11)[0]
        idx = np.frombuffer(bio.read(alen), '<u8')
        if idx.shape[0] * 8 != alen:
            raise BagError('message index at byte %d is truncated' % ch.message_index_offsets[cid])
        idx = idx.reshape(-1, 2)
        t_ns = idx[:, 0].astype(np.int64)
        off = idx[:, 1].astype(np.int64)
        buf = np.frombuffer(raw, np.uint8)
        if off.size and (off.max() + 31 > buf.shape[0] or (buf[off] != 0x05).any()):
            raise BagError('message offsets of chunk at byte %d are invalid'
                           % ch.chunk_start_offset)
        lens = _gather_u64(buf, off + 1) - 22
        if off.size and (lens < 0).any():
            raise BagError('invalid message record length in chunk at byte %d'
                           % ch.chunk_start_offset)
        start = off + 31
        if off.size and (start + lens).max() > buf.shape[0]:
            raise BagError('message exceeds its chunk at byte %d' % ch.chunk_start_offset)
        if off.size and (lens == lens[0]).all():
            rows = buf[start[:, None] + np.arange(int(lens[0]))]
        else:
            rows = [raw[s:s + n] for s, n in zip(start.tolist(), lens.tolist())]
        if t_ns.size > 1 and (np.diff(t_ns) < 0).any():
            order = np.argsort(t_ns, kind='stable')
            t_ns = t_ns[order]
            rows = rows[order] if isinstance(rows, np.ndarray) else [rows[i] for i in order]
        yield t_ns, rows


def _gather_u64(buf, pos):
    """Return the little-endian uint64 at each byte offset ``pos`` of ``buf`` as int64."""
    b = buf[pos[:, None] + np.arange(8)]
    return np.ascontiguousarray(b).view('<u8').reshape(-1).astype(np.int64)


def read_streams(path, keys=None):
    """
    Read the graph streams of a bag; return (streams dict, lockstep flag, all topics).

    :param keys: stream keys to read (default every key of :data:`GRAPH_TOPICS` present).
    """
    with BagReader(path) as bag:
        keys = list(GRAPH_TOPICS) if keys is None else list(keys)
        streams = {k: s for k in keys if (s := bag.read(k)) is not None}
        return streams, bag.is_lockstep(), bag.all_topics


def read_hysteresis_experiment(path):
    """
    Return (t s, u V, y m) of a hysteresis experiment bag (drive_voltage vs displacement).

    ``y`` is the displacement position, ``t`` its header stamp relative to the first
    sample, ``u`` the drive voltage applied during each sample's period, aligned as in
    :func:`fiber_align.analysis.report.align_to_samples` (by order in lockstep bags, by
    receive time otherwise).

    :raises BagError: the bag is unreadable or lacks ``drive_voltage`` or ``displacement``.
    """
    streams, lockstep, _ = read_streams(path, ['displacement', 'drive_voltage', 'clock'])
    missing = [k for k in ('displacement', 'drive_voltage') if k not in streams]
    if missing:
        raise BagError('bag %s has no %s topic: not a hysteresis experiment'
                       % (path, ' or '.join(missing)))
    al = align_to_samples(streams, lockstep)
    u = al['drive_voltage']
    ok = np.isfinite(u)
    return al['t'][ok], u[ok], al['y'][ok]
