# SPDX-License-Identifier: Apache-2.0
"""
CDR encoding of the graph's fixed-layout messages, vectorised over messages (numpy).

``std_msgs/Float64``, ``sensor_msgs/JointState`` (one joint), ``std_msgs/Float64MultiArray``
and ``rosgraph_msgs/Clock`` rows, byte-identical to rosbags' ``serialize_cdr``
(little-endian CDR). Values are SI (m, m/s, V); stamps int64 ns.
"""

import struct

import numpy as np

from fiber_align.analysis.bag.common import _CDR_LE, CONTROLLER_LABELS


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
