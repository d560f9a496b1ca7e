# SPDX-License-Identifier: Apache-2.0
"""
An rclpy message's CDR for a bag, packed by a plan made once per type (:func:`packer`).

CDR, little endian, each number aligned to its size up to 8 from the start of the
payload: the types a control period publishes (numbers, strings, their sequences and
nested messages: ``Float64``, ``JointState``, ``Float64MultiArray``) packed in order
with :mod:`struct`. :func:`adapter` shows an rclpy message to rosbags' serialisers (its
numeric sequences as numpy views); :func:`same` compares two messages field by field, a
NaN equal to a NaN. The encoder that checks a packer against rosbags and rclpy before
trusting it is ``nodes.ros.cdr.Encoder``; nothing here imports rclpy (the message
classes come from ``rosidl_runtime_py`` when a type is planned).
"""

import struct
import sys

import numpy as np

from fiber_align.analysis.bag.common import _CDR_LE

#: rclpy field type of a numeric sequence -> numpy dtype (rclpy holds them as
#: ``array.array``; fixed-size arrays are numpy arrays already).
_SEQUENCES = {'sequence<%s>' % k: v for k, v in (
    ('double', np.float64), ('float', np.float32), ('int8', np.int8), ('uint8', np.uint8),
    ('int16', np.int16), ('uint16', np.uint16), ('int32', np.int32),
    ('uint32', np.uint32), ('int64', np.int64), ('uint64', np.uint64))}


#: rclpy field type -> (struct code, size in bytes) of the numbers :func:`packer` packs
NUMBERS = {'double': ('d', 8), 'float': ('f', 4), 'int8': ('b', 1), 'uint8': ('B', 1),
           'int16': ('h', 2), 'uint16': ('H', 2), 'int32': ('i', 4), 'uint32': ('I', 4),
           'int64': ('q', 8), 'uint64': ('Q', 8), 'boolean': ('?', 1)}
_U32 = struct.Struct('<I')


class _Plan:
    """
    The source of one message type's packing function, straight-line (see :func:`packer`).

    Numbers whose offset is known while planning are gathered into one ``struct`` call
    with their padding; after a string or a sequence the offset is only known when
    packing, and the padding is computed there.
    """

    def __init__(self):
        """Start at the payload's offset 0, nothing gathered."""
        self.lines, self.consts = [], {}
        self.offset = 0             # the payload's length while known, else None
        self.fmt, self.args = '', []

    def const(self, value):
        """Return the name of a constant of the generated code."""
        name = '_c%d' % len(self.consts)
        self.consts[name] = value
        return name

    def flush(self, indent):
        """Emit the numbers gathered so far as one ``struct`` call."""
        if self.fmt:
            self.lines.append('%sb += %s.pack(%s)' % (indent, self.const(
                struct.Struct('<' + self.fmt)), ', '.join(self.args)))
            self.fmt, self.args = '', []

    def pad(self, size, indent):
        """Align the payload to ``size`` bytes (statically when the offset is known)."""
        if self.offset is not None:
            n = -self.offset % size
            self.fmt += 'x' * n
            self.offset += n
        elif size > 1:
            self.flush(indent)
            self.lines.append('%sb += _ZEROS[:(4 - len(b)) %% %d]' % (indent, size))

    def number(self, typ, expr, indent):
        code, size = NUMBERS[typ]
        self.pad(size, indent)
        self.fmt += code
        self.args.append(expr)
        if self.offset is not None:
            self.offset += size

    def message(self, cls, expr, indent, depth=0):
        """Plan every field of ``cls`` read from ``expr``; False: a field it cannot plan."""
        fields = cls.get_fields_and_field_types()
        if not fields:
            return False    # an empty message carries a placeholder byte: not planned
        return all(self.field(typ, '%s.%s' % (expr, name), indent, depth)
                   for name, typ in fields.items())

    def field(self, typ, expr, indent, depth):
        if typ in NUMBERS:
            self.number(typ, expr, indent)
            return True
        seq = typ[len('sequence<'):-1] if typ.startswith('sequence<') and typ.endswith(
            '>') else None
        if typ != 'string' and seq is None:
            sub = _message_class(typ)
            return sub is not None and self.message(sub, expr, indent, depth)
        self.pad(4, indent)
        self.flush(indent)
        self.offset = None
        v = '_v%d' % depth
        self.lines.append('%s%s = %s' % (indent, v, expr))
        if typ == 'string':
            self.lines.append('%s_s = %s.encode()' % (indent, v))
            self.lines.append('%sb += _U32.pack(len(_s) + 1) + _s + _NUL' % indent)
            return True
        self.lines.append('%sb += _U32.pack(len(%s))' % (indent, v))
        if seq in NUMBERS and seq != 'boolean':
            code, size = NUMBERS[seq]
            # array.array / numpy hold the machine's order (little, checked); lists pack
            self.lines.append('%sif len(%s):' % (indent, v))
            if size > 1:
                self.lines.append('%s    b += _ZEROS[:(4 - len(b)) %% %d]' % (indent, size))
            self.lines.append("%s    b += %s.tobytes() if hasattr(%s, 'tobytes') else "
                              "struct.pack('<%%d%s' %% len(%s), *%s)"
                              % (indent, v, v, code, v, v))
            return True
        sub = None if seq is None else 'string' if seq == 'string' else _message_class(seq)
        if sub is None:
            return False
        e = '_e%d' % depth
        self.lines.append('%sfor %s in %s:' % (indent, e, v))
        inner = indent + '    '
        if sub == 'string':
            ok = self.field('string', e, inner, depth + 1)
        else:
            ok = self.message(sub, e, inner, depth + 1)
        self.flush(inner)
        self.offset = None
        return ok


def _message_class(typ):
    """Return the rclpy class of the message type name ``typ``, or None (not a message)."""
    if '/' not in typ or '[' in typ or '<' in typ:
        return None     # fixed arrays, bounded strings, wide strings: not planned
    from rosidl_runtime_py.utilities import get_message
    try:
        return get_message(typ if typ.count('/') == 2 else typ.replace('/', '/msg/'))
    except (AttributeError, ModuleNotFoundError, ValueError):
        return None


def packer(cls):
    """
    Return ``msg -> bytes`` packing an rclpy message of ``cls`` as CDR, or None.

    None for a type with a field it does not plan (bounded strings, wide strings, fixed
    arrays, octets) or on a big-endian machine; :class:`Encoder` checks its first result
    against rosbags'.
    """
    if sys.byteorder != 'little':
        return None
    plan = _Plan()
    if not plan.message(cls, 'm', '    '):
        return None
    plan.flush('    ')
    source = 'def pack(m):\n    b = bytearray(_HEAD)\n%s\n    return bytes(b)\n' % (
        '\n'.join(plan.lines))
    scope = dict(plan.consts, _HEAD=_CDR_LE, _ZEROS=bytes(8), _U32=_U32, _NUL=b'\x00',
                 struct=struct)
    exec(compile(source, '<cdr packer of %s>' % cls.__name__, 'exec'), scope)  # noqa: S102
    return scope['pack']


def same(a, b):
    """Return True when rclpy messages (or field values) ``a`` and ``b`` are equal, NaN too."""
    if hasattr(a, 'get_fields_and_field_types'):
        return type(a) is type(b) and all(same(getattr(a, f), getattr(b, f))
                                          for f in a.get_fields_and_field_types())
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (a != a and b != b)
    if isinstance(a, (str, bytes, bool, int)) or a is None:
        return a == b
    try:
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    except TypeError:
        return a == b


class _View:
    """A message's fields as rosbags reads them (attribute access only)."""

    def __init__(self, fields):
        self.__dict__.update(fields)


def adapter(cls):
    """
    Return ``msg -> object`` that rosbags can serialise, or ``None`` (the message as is).

    Numeric sequences become numpy views of the same memory; nested messages that hold
    one are adapted in turn; every other field is passed as it is.
    """
    from rosidl_runtime_py.utilities import get_message
    plan = []
    for name, typ in cls.get_fields_and_field_types().items():
        if typ in _SEQUENCES:
            plan.append((name, _SEQUENCES[typ], None))
        elif '/' in typ and not typ.startswith('sequence<') and '[' not in typ:
            sub = adapter(get_message(typ if typ.count('/') == 2 else
                                      typ.replace('/', '/msg/')))
            plan.append((name, None, sub))
        else:
            plan.append((name, None, None))
    if all(dt is None and sub is None for _, dt, sub in plan):
        return None
    frombuffer = np.frombuffer

    def adapt(msg):
        out = {}
        for name, dt, sub in plan:
            v = getattr(msg, name)
            if dt is not None:
                v = frombuffer(v, dtype=dt)
            elif sub is not None:
                v = sub(v)
            out[name] = v
        return _View(out)
    return adapt
