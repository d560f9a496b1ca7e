# SPDX-License-Identifier: Apache-2.0
"""
Read and write the graph's rosbag2 bags (mcap and sqlite3) with rosbags, fast.

Reading streams the raw CDR bytes of one topic at a time and decodes them in vectorised
numpy batches when the message layout is fixed (``std_msgs/Float64``, ``rosgraph_msgs/Clock``,
``sensor_msgs/JointState`` and ``std_msgs/Float64MultiArray`` whose names, labels and sizes
do not change); any other layout falls back to rosbags' ``deserialize_cdr`` per message.
Output arrays are allocated once from the bag's per-topic message counts, so memory is
bounded by the decoded arrays themselves plus one chunk of raw bytes.

Topics are found by the last component of their name, so a graph run under any
namespace is read the same (``/rig1/displacement`` is the ``displacement`` stream).

Times: bag (receive) timestamps are int64 ns; header stamps are int64 ns. Values are SI
(m, m/s, V, W).
"""

from dataclasses import dataclass, field
import itertools
from pathlib import Path
import struct

import numpy as np

from fiber_align.analysis.report import align_to_samples

FLOAT64 = 'std_msgs/msg/Float64'
JOINT_STATE = 'sensor_msgs/msg/JointState'
MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'
CLOCK = 'rosgraph_msgs/msg/Clock'
DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'
STRING = 'std_msgs/msg/String'

#: The graph's streams: last name component -> message type.
GRAPH_TOPICS = {
    'setpoint': FLOAT64,
    'displacement': JOINT_STATE,
    'feedforward_voltage': FLOAT64,
    'feedback_voltage': FLOAT64,
    'drive_voltage': FLOAT64,
    'optical_power': FLOAT64,
    'controller_state': MULTI_ARRAY,
    'diagnostics': DIAGNOSTICS,
    'clock': CLOCK,
    'alignment_state': STRING,
}

#: Default labels of ``controller_state`` (Float64MultiArray dim labels).
CONTROLLER_LABELS = ('error', 'error_rate', 'kp', 'ki', 'kd', 'output')

_CDR_LE = b'\x00\x01\x00\x00'
_BATCH = 1 << 16


class BagError(ValueError):
    """A bag cannot be opened or read; the message says which bag and why."""


def typestore():
    """Return the rosbags typestore pinned to ROS 2 Jazzy."""
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


@dataclass
class Stream:
    """
    One decoded topic.

    ``t_ns`` holds the bag (receive) timestamps in ns, in the order the messages were
    written; ``fields`` maps field names to arrays of the same length (SI units):
    Float64 -> ``data``; JointState -> ``stamp_ns``, ``position``, ``velocity`` (first
    joint); Float64MultiArray -> ``data`` (N x M) with ``labels``; Clock -> ``clock_ns``;
    other types -> ``msgs`` (a list of rosbags message objects).
    """

    topic: str
    msgtype: str
    t_ns: np.ndarray
    fields: dict = field(default_factory=dict)
    labels: tuple = ()
    decoder: str = 'numpy'

    def __len__(self):
        """Return the number of messages."""
        return int(self.t_ns.shape[0])


def _storage_plugin(storage):
    from rosbags.rosbag2 import StoragePlugin
    s = str(storage).lower()
    if s == 'mcap':
        return StoragePlugin.MCAP
    if s in ('sqlite3', 'sqlite', 'db3'):
        return StoragePlugin.SQLITE3
    raise ValueError('storage must be mcap or sqlite3, got %r' % storage)


# --------------------------------------------------------------------------- CDR encoding

def _align(n, a):
    return (n + a - 1) // a * a


def _cdr_string(buf, s):
    """Append a CDR string to ``buf`` (bytearray holding the payload after the header)."""
    b = s.encode('utf-8') + b'\x00'
    buf.extend(b'\x00' * (_align(len(buf), 4) - len(buf)))
    buf.extend(struct.pack('<I', len(b)))
    buf.extend(b)


def _cdr_u32(buf, v):
    buf.extend(b'\x00' * (_align(len(buf), 4) - len(buf)))
    buf.extend(struct.pack('<I', v))


def _cdr_i32(buf, v):
    buf.extend(b'\x00' * (_align(len(buf), 4) - len(buf)))
    buf.extend(struct.pack('<i', v))


def joint_state_template(name='bimorph_tip', frame_id=''):
    """
    Return (template bytes, stamp offset, position offset, velocity offset) of a JointState.

    The template is the CDR of a one-joint JointState (position, velocity, no effort);
    offsets are byte offsets into the whole message (header included).
    """
    buf = bytearray()
    _cdr_i32(buf, 0)
    _cdr_u32(buf, 0)
    _cdr_string(buf, frame_id)
    _cdr_u32(buf, 1)
    _cdr_string(buf, name)
    _cdr_u32(buf, 1)
    buf.extend(b'\x00' * (_align(len(buf), 8) - len(buf)))
    pos = len(buf)
    buf.extend(b'\x00' * 8)
    _cdr_u32(buf, 1)
    buf.extend(b'\x00' * (_align(len(buf), 8) - len(buf)))
    vel = len(buf)
    buf.extend(b'\x00' * 8)
    _cdr_u32(buf, 0)
    return _CDR_LE + bytes(buf), 4, 4 + pos, 4 + vel


def multiarray_template(labels):
    """
    Return (template bytes, data offset) of a Float64MultiArray, one dim per label.

    Each dim has size 1 and stride 1; the data holds ``len(labels)`` doubles.
    """
    buf = bytearray()
    _cdr_u32(buf, len(labels))
    for lab in labels:
        _cdr_string(buf, lab)
        _cdr_u32(buf, 1)
        _cdr_u32(buf, 1)
    _cdr_u32(buf, 0)            # data_offset
    _cdr_u32(buf, len(labels))  # data length
    buf.extend(b'\x00' * (_align(len(buf), 8) - len(buf)))
    off = len(buf)
    buf.extend(b'\x00' * (8 * len(labels)))
    return _CDR_LE + bytes(buf), 4 + off


def encode_float64(values):
    """
    Return an (N, 12) uint8 array of CDR ``std_msgs/Float64`` messages for ``values``.

    CDR alignment counts from the end of the 4-byte encapsulation header, so the double
    follows the header directly (no padding): 4 + 8 bytes.
    """
    v = np.ascontiguousarray(values, dtype='<f8')
    out = np.empty((v.shape[0], 12), np.uint8)
    out[:, :4] = np.frombuffer(_CDR_LE, np.uint8)
    out[:, 4:12] = v.view(np.uint8).reshape(-1, 8)
    return out


def encode_joint_state(stamp_ns, position, velocity=None, name='bimorph_tip'):
    """Return an (N, L) uint8 array of CDR JointState messages (stamp ns, position m, m/s)."""
    tpl, so, po, vo = joint_state_template(name)
    stamp_ns = np.asarray(stamp_ns, np.int64)
    n = stamp_ns.shape[0]
    out = np.empty((n, len(tpl)), np.uint8)
    out[:] = np.frombuffer(tpl, np.uint8)
    sec = (stamp_ns // 1_000_000_000).astype('<i4')
    nsec = (stamp_ns % 1_000_000_000).astype('<u4')
    out[:, so:so + 4] = sec.view(np.uint8).reshape(-1, 4)
    out[:, so + 4:so + 8] = nsec.view(np.uint8).reshape(-1, 4)
    out[:, po:po + 8] = np.ascontiguousarray(position, '<f8').view(np.uint8).reshape(-1, 8)
    vel = np.zeros(n) if velocity is None else velocity
    out[:, vo:vo + 8] = np.ascontiguousarray(vel, '<f8').view(np.uint8).reshape(-1, 8)
    return out


def encode_multiarray(data, labels=CONTROLLER_LABELS):
    """Return an (N, L) uint8 array of CDR Float64MultiArray messages, one dim per label."""
    tpl, off = multiarray_template(labels)
    d = np.ascontiguousarray(data, '<f8')
    out = np.empty((d.shape[0], len(tpl)), np.uint8)
    out[:] = np.frombuffer(tpl, np.uint8)
    out[:, off:off + 8 * len(labels)] = d.view(np.uint8).reshape(d.shape[0], -1)
    return out


def encode_clock(clock_ns):
    """Return an (N, 12) uint8 array of CDR ``rosgraph_msgs/Clock`` messages."""
    c = np.asarray(clock_ns, np.int64)
    out = np.zeros((c.shape[0], 12), np.uint8)
    out[:, :4] = np.frombuffer(_CDR_LE, np.uint8)
    out[:, 4:8] = (c // 1_000_000_000).astype('<i4').view(np.uint8).reshape(-1, 4)
    out[:, 8:12] = (c % 1_000_000_000).astype('<u4').view(np.uint8).reshape(-1, 4)
    return out


# --------------------------------------------------------------------------- writing

def write_bag(path, series, storage='mcap', namespace='', chunk=_BATCH):
    """
    Write the graph's topics to a new rosbag2 (version 9) bag with rosbags.

    :param path: bag directory to create (must not exist).
    :param series: mapping of topic last name -> dict with ``t_ns`` (int64 receive times,
        ns) and, by type: Float64 ``data`` (SI); JointState ``stamp_ns``, ``position`` (m),
        optional ``velocity`` (m/s); Float64MultiArray ``data`` (N x M) and optional
        ``labels``; Clock ``clock_ns``; String ``data`` (list of str); DiagnosticArray
        ``msgs`` (rosbags message objects). A value may also be a callable returning an
        iterator of such dicts (chunks), so huge bags are written with bounded memory.
    :param storage: ``mcap`` or ``sqlite3``.
    :param namespace: prefix for relative topics (``/diagnostics`` and ``/clock`` stay
        absolute).
    :returns: the bag path.
    """
    from rosbags.rosbag2 import Writer
    ts = typestore()
    path = Path(path)
    writer = Writer(path, version=9, storage_plugin=_storage_plugin(storage))
    writer.open()
    try:
        conns = {}
        for key in series:
            if key not in GRAPH_TOPICS:
                raise ValueError('unknown topic %r (known: %s)' % (key, ', '.join(GRAPH_TOPICS)))
            if key in ('diagnostics', 'clock'):
                name = '/' + key
            else:
                name = '/'.join(['', namespace.strip('/'), key]).replace('//', '/')
            conns[key] = writer.add_connection(name, GRAPH_TOPICS[key], typestore=ts)
        for key, value in series.items():
            parts = value() if callable(value) else [value]
            for part in parts:
                _write_part(writer, conns[key], key, part, ts, chunk)
    except BaseException:
        writer.close()
        raise
    writer.close()
    return path


def _write_part(writer, conn, key, part, ts, chunk):
    t_ns = np.asarray(part['t_ns'], np.int64)
    mtype = GRAPH_TOPICS[key]
    if mtype == FLOAT64:
        rows = encode_float64(part['data'])
    elif mtype == JOINT_STATE:
        rows = encode_joint_state(part['stamp_ns'], part['position'], part.get('velocity'))
    elif mtype == MULTI_ARRAY:
        rows = encode_multiarray(part['data'], part.get('labels', CONTROLLER_LABELS))
    elif mtype == CLOCK:
        rows = encode_clock(part['clock_ns'])
    elif mtype == STRING:
        msg_cls = ts.types[STRING]
        for t, s in zip(t_ns, part['data']):
            writer.write(conn, int(t), ts.serialize_cdr(msg_cls(data=str(s)), STRING))
        return
    else:
        for t, m in zip(t_ns, part['msgs']):
            writer.write(conn, int(t), ts.serialize_cdr(m, mtype))
        return
    if rows.shape[0] != t_ns.shape[0]:
        raise ValueError('%s: %d timestamps for %d messages' % (key, t_ns.shape[0], rows.shape[0]))
    if _mcap_write_rows(writer, conn, t_ns, rows):
        return
    write = writer.write
    for i0 in range(0, rows.shape[0], chunk):
        blk = rows[i0:i0 + chunk]
        tb = t_ns[i0:i0 + chunk].tolist()
        for t, row in zip(tb, blk):
            write(conn, t, row.tobytes())


def _mcap_write_rows(writer, conn, t_ns, rows):
    """
    Write fixed-size messages as whole MCAP chunks built with numpy; False if not possible.

    Equivalent to rosbags' McapWriter (same records, one channel per chunk, uncompressed,
    chunk of about 1 MiB) but without a Python call per message. Uses rosbags internals,
    so any mismatch (other storage, compression, other version) makes it decline and the
    caller writes message by message.
    """
    st = getattr(writer, 'storage', None)
    if type(st).__name__ != 'McapWriter' or getattr(st, 'compression', None) != '' or \
            not hasattr(st, 'chunks') or not hasattr(st, 'chunk'):
        return False
    from io import BytesIO
    from rosbags.rosbag2.storage_mcap import write_record, write_string, write_uint16, \
        write_uint32, write_uint64
    if st.chunk.bio.tell():
        st.close_chunk()
    n, width = rows.shape
    size = 31 + width
    per = max(1, (1 << 20) // size)
    cid = conn.id
    for i0 in range(0, n, per):
        blk = rows[i0:i0 + per]
        tb = np.ascontiguousarray(t_ns[i0:i0 + per], '<u8')
        m = blk.shape[0]
        arr = np.empty((m, size), np.uint8)
        arr[:, 0] = 0x05
        arr[:, 1:9] = np.frombuffer(struct.pack('<Q', 22 + width), np.uint8)
        arr[:, 9:11] = np.frombuffer(struct.pack('<H', cid), np.uint8)
        arr[:, 11:15] = 0
        arr[:, 15:23] = tb.view(np.uint8).reshape(m, 8)
        arr[:, 23:31] = arr[:, 15:23]
        arr[:, 31:] = blk
        data = arr.tobytes()
        t0, t1 = int(tb.min()), int(tb.max())
        rec = BytesIO()
        for v in (t0, t1, len(data)):
            write_uint64(rec, v)
        write_uint32(rec, 0)
        write_string(rec, '')
        write_uint64(rec, len(data))
        rec.write(data)
        chunk_start = st.bio.tell()
        write_record(st.bio, 0x06, rec)
        chunk_end = st.bio.tell()
        idx = np.empty((m, 2), '<u8')
        idx[:, 0] = tb
        idx[:, 1] = np.arange(m, dtype=np.uint64) * size
        rec = BytesIO()
        write_uint16(rec, cid)
        write_uint32(rec, m * 16)
        rec.write(idx.tobytes())
        write_record(st.bio, 0x07, rec)
        rec = BytesIO()
        for v in (t0, t1, chunk_start, chunk_end - chunk_start):
            write_uint64(rec, v)
        write_uint32(rec, 10)
        write_uint16(rec, cid)
        write_uint64(rec, chunk_end)
        write_uint64(rec, st.bio.tell() - chunk_end)
        write_string(rec, '')
        write_uint64(rec, len(data))
        write_uint64(rec, len(data))
        st.chunks.append(rec)
        st.message_start_time = min(t0, st.message_start_time)
        st.message_end_time = max(t1, st.message_end_time)
        st.channel_stats[cid] = st.channel_stats.get(cid, 0) + m
    if n:
        writer.counts[cid] += n
        writer.min_timestamp = min(int(t_ns.min()), writer.min_timestamp)
        writer.max_timestamp = max(int(t_ns.max()), writer.max_timestamp)
    return True


# --------------------------------------------------------------------------- reading

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


def last_name(topic):
    """Return the last component of a topic name (``/ns/displacement`` -> ``displacement``)."""
    return topic.rstrip('/').rsplit('/', 1)[-1]


def discover(connections):
    """
    Map graph stream keys to connections, whatever the namespace.

    A topic matches a key when its last name component equals the key and its type is
    the key's type. A ``std_msgs/String`` topic whose last name contains ``state`` or
    ``alignment`` is taken as ``alignment_state`` if no topic is named so. When several
    topics match a key (several namespaces), the one with most messages wins.
    """
    found = {}
    for c in connections:
        key = last_name(c.topic)
        if GRAPH_TOPICS.get(key) == c.msgtype:
            prev = found.get(key)
            if prev is None or c.msgcount > prev.msgcount:
                found[key] = c
    if 'alignment_state' not in found:
        for c in connections:
            nm = last_name(c.topic)
            if c.msgtype == STRING and ('state' in nm or 'alignment' in nm):
                found['alignment_state'] = c
                break
    return found


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


# --------------------------------------------------------------------------- decoding

class _Walker:
    """Walk a little-endian CDR message, recording which bytes are padding."""

    def __init__(self, row):
        self.row = bytes(row)
        self.o = 4
        self.pad = np.zeros(len(self.row), bool)

    def align(self, a):
        o2 = _align(self.o - 4, a) + 4
        self.pad[self.o:o2] = True
        self.o = o2

    def u32(self):
        self.align(4)
        if self.o + 4 > len(self.row):
            raise IndexError('message too short')
        v = struct.unpack_from('<I', self.row, self.o)[0]
        self.o += 4
        return v

    def string(self):
        n = self.u32()
        s = self.row[self.o:self.o + n - 1].decode('utf-8', 'replace')
        self.o += n
        return s


def _joint_state_layout(row):
    """
    Return ((position, velocity, effort) (offset, n) pairs, struct mask) of a JointState.

    Offsets are into the whole message; the mask marks the bytes that must be equal in
    every message of a fixed-layout stream (all but the stamp, padding and doubles).
    """
    if bytes(row[:4]) != _CDR_LE:
        return None
    w = _Walker(row)
    try:
        w.o = 12                    # stamp: int32 sec, uint32 nanosec
        w.string()                  # frame_id
        for _ in range(w.u32()):    # names
            w.string()
        offs = []
        for _ in range(3):          # position, velocity, effort
            n = w.u32()
            if n:
                w.align(8)
            offs.append((w.o, n))
            w.o += 8 * n
    except (IndexError, struct.error):
        return None
    if not 0 <= len(w.row) - w.o < 8:
        return None
    w.pad[w.o:] = True              # Fast DDS pads the payload end to 8 bytes
    mask = ~w.pad
    mask[4:12] = False
    for a, n in offs:
        mask[a:a + 8 * n] = False
    return offs, mask


def _multiarray_layout(row):
    """Return (labels, data offset, n values, struct mask) of one Float64MultiArray."""
    if bytes(row[:4]) != _CDR_LE:
        return None
    w = _Walker(row)
    try:
        labels = []
        for _ in range(w.u32()):
            labels.append(w.string())
            w.u32()                 # size
            w.u32()                 # stride
        w.u32()                     # data_offset
        n = w.u32()
        if n:
            w.align(8)
    except (IndexError, struct.error):
        return None
    o = w.o
    if not 0 <= len(w.row) - (o + 8 * n) < 8:
        return None
    w.pad[o + 8 * n:] = True
    mask = ~w.pad
    mask[o:o + 8 * n] = False
    return tuple(labels), o, n, mask


def _col_f64(rows, o):
    return np.ascontiguousarray(rows[:, o:o + 8]).view('<f8').reshape(-1)


def _stamp_ns(rows, o):
    sec = np.ascontiguousarray(rows[:, o:o + 4]).view('<i4').reshape(-1).astype(np.int64)
    nsec = np.ascontiguousarray(rows[:, o + 4:o + 8]).view('<u4').reshape(-1).astype(np.int64)
    return sec * 1_000_000_000 + nsec


class _Fast:
    """Vectorised decoder for one fixed-layout stream; ``None`` from decode means fall back."""

    def __init__(self, msgtype):
        self.msgtype = msgtype
        self.ref = None
        self.layout = None
        self.labels = ()

    def decode(self, rows):
        """Return a dict of arrays for an (n, L) uint8 batch, or None to fall back."""
        if not isinstance(rows, np.ndarray):
            return None
        if rows.shape[0] == 0:
            return {}
        if self.ref is None:
            self.ref = rows[0].copy()
            if not self._learn(self.ref):
                return None
        if rows.shape[1] != self.ref.shape[0]:
            return None
        m = self.mask
        if not (rows[:, m] == self.ref[m]).all():
            return None
        return self._extract(rows)

    def _learn(self, row):
        t = self.msgtype
        if t == FLOAT64 or t == CLOCK:
            if row.shape[0] not in (12, 16):   # 16: payload end padded to 8 bytes
                return False
            self.mask = np.zeros(row.shape[0], bool)
            self.mask[:4] = True
            return True
        if t == JOINT_STATE:
            lay = _joint_state_layout(row)
            if lay is None or lay[0][0][1] < 1:
                return False
            self.layout, self.mask = lay
            return True
        if t == MULTI_ARRAY:
            lay = _multiarray_layout(row)
            if lay is None:
                return False
            self.labels, self.off, self.n, self.mask = lay
            return True
        return False

    def _extract(self, rows):
        t = self.msgtype
        if t == FLOAT64:
            return {'data': _col_f64(rows, 4)}
        if t == CLOCK:
            return {'clock_ns': _stamp_ns(rows, 4)}
        if t == JOINT_STATE:
            (po, pn), (vo, vn), _ = self.layout
            out = {'stamp_ns': _stamp_ns(rows, 4), 'position': _col_f64(rows, po)}
            out['velocity'] = _col_f64(rows, vo) if vn else np.full(rows.shape[0], np.nan)
            return out
        o, n = self.off, self.n
        blk = np.ascontiguousarray(rows[:, o:o + 8 * n]).view('<f8')
        return {'data': blk.reshape(rows.shape[0], n)}


def _deserialize(ts, data, msgtype):
    """Deserialise CDR ``data``; tolerate the up to 7 end padding bytes Fast DDS adds."""
    try:
        return ts.deserialize_cdr(data, msgtype)
    except Exception:
        for k in range(1, 8):
            try:
                return ts.deserialize_cdr(data[:-k], msgtype)
            except Exception:  # noqa: BLE001 - try the next shorter length
                continue
        raise


def _slow_decode(ts, msgtype, rows, state):
    """Decode a batch with rosbags' deserializer; return a dict of arrays (or msgs)."""
    msgs = [_deserialize(ts, bytes(r), msgtype) for r in rows]
    if msgtype == FLOAT64:
        return {'data': np.array([m.data for m in msgs], float)}
    if msgtype == CLOCK:
        return {'clock_ns': np.array([m.clock.sec * 10**9 + m.clock.nanosec for m in msgs],
                                     np.int64)}
    if msgtype == JOINT_STATE:
        def first(a):
            return float(a[0]) if len(a) else np.nan
        return {'stamp_ns': np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                                      for m in msgs], np.int64),
                'position': np.array([first(m.position) for m in msgs], float),
                'velocity': np.array([first(m.velocity) for m in msgs], float)}
    if msgtype == MULTI_ARRAY:
        if msgs and not state.get('labels'):
            state['labels'] = tuple(d.label for d in msgs[0].layout.dim)
        width = len(state.get('labels') or ()) or max((len(m.data) for m in msgs), default=0)
        state.setdefault('width', width)
        out = np.full((len(msgs), state['width']), np.nan)
        for i, m in enumerate(msgs):
            k = min(len(m.data), state['width'])
            out[i, :k] = m.data[:k]
        return {'data': out}
    return {'msgs': msgs}


def _decode(bag, conn, keep=None, stride=1):
    """Decode the messages of ``conn`` into a :class:`Stream` (arrays preallocated)."""
    stride = max(1, int(stride))
    n = -(-int(conn.msgcount) // stride)
    g = 0
    t_all = np.empty(n, np.int64)
    store = {}
    msgs = []
    fast = _Fast(conn.msgtype)
    ts = None
    state = {}
    used_slow = False
    i = 0
    for t_ns, rows in bag.raw_batches(conn):
        if stride > 1:
            sel = np.nonzero((np.arange(g, g + t_ns.shape[0]) % stride) == 0)[0]
            g += t_ns.shape[0]
            t_ns = t_ns[sel]
            rows = rows[sel] if isinstance(rows, np.ndarray) else [rows[j] for j in sel]
        k = t_ns.shape[0]
        out = fast.decode(rows) if conn.msgtype != DIAGNOSTICS and conn.msgtype != STRING \
            else None
        if out is None:
            ts = ts or typestore()
            out = _slow_decode(ts, conn.msgtype, rows, state)
            used_slow = True
        if i + k > t_all.shape[0]:
            t_all = np.concatenate([t_all, np.empty(i + k - t_all.shape[0], np.int64)])
        t_all[i:i + k] = t_ns
        for name, arr in out.items():
            if keep is not None and name not in keep:
                continue
            if name == 'msgs':
                msgs.extend(arr)
                continue
            dst = store.get(name)
            if dst is None:
                shape = (max(n, i + k),) + arr.shape[1:]
                dst = store[name] = np.full(shape, np.nan, arr.dtype) \
                    if arr.dtype.kind == 'f' else np.zeros(shape, arr.dtype)
            if dst.shape[1:] != arr.shape[1:]:
                raise BagError('%s changes its array width' % conn.topic)
            if i + k > dst.shape[0]:
                dst = store[name] = np.concatenate(
                    [dst, np.zeros((i + k - dst.shape[0],) + dst.shape[1:], dst.dtype)])
            dst[i:i + k] = arr
        i += k
    fields = {name: arr[:i] for name, arr in store.items()}
    if msgs:
        fields['msgs'] = msgs
    labels = fast.labels or state.get('labels') or ()
    if conn.msgtype == MULTI_ARRAY and not labels and 'data' in fields:
        labels = CONTROLLER_LABELS[:fields['data'].shape[1]]
    return Stream(conn.topic, conn.msgtype, t_all[:i], fields, tuple(labels),
                  'rosbags' if used_slow else 'numpy')


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
