# SPDX-License-Identifier: Apache-2.0
"""
Write the graph's streams to a rosbag2 bag (mcap or sqlite3) with rosbags, in batches.

Rows are encoded by :mod:`fiber_align.analysis.bag.cdr`; times are int64 ns, values SI.
"""

from pathlib import Path
import struct

import numpy as np

from fiber_align.analysis.bag.cdr import (encode_clock, encode_float64, encode_joint_state,
                                          encode_multiarray)
from fiber_align.analysis.bag.common import (_BATCH, storage_plugin, CLOCK,
                                             CONTROLLER_LABELS, FLOAT64, GRAPH_TOPICS,
                                             JOINT_STATE, MULTI_ARRAY, STRING, typestore)


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
    writer = Writer(path, version=9, storage_plugin=storage_plugin(storage))
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
