# SPDX-License-Identifier: Apache-2.0
"""
Decode one topic's raw CDR rows into arrays: vectorised for fixed layouts, else rosbags.

A fixed layout (``std_msgs/Float64``, ``rosgraph_msgs/Clock``, ``sensor_msgs/JointState``
and ``std_msgs/Float64MultiArray`` whose names, labels and sizes do not change) is
learned from the first row and read from every row with numpy; any other layout falls
back to rosbags' ``deserialize_cdr`` per message. Output arrays are allocated once from
the topic's message count. Values SI, times int64 ns.
"""

import struct

import numpy as np

from fiber_align.analysis.bag.cdr import _align
from fiber_align.analysis.bag.common import (_CDR_LE, BagError, CLOCK, CONTROLLER_LABELS,
                                             DIAGNOSTICS, FLOAT64, JOINT_STATE, MULTI_ARRAY,
                                             Stream, STRING, typestore)


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
