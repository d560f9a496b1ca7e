# SPDX-License-Identifier: Apache-2.0
"""
The CDR bytes of an rclpy message as a bag stores them, without DDS (:func:`encoder`).

The in-process recorder (``bag_recorder`` hosted in ``control_graph``) receives the
Python message objects of its process's nodes, not DDS's bytes. rosbags' generated
serialisers read the fields by attribute, so they serialise an rclpy message as they
would one of their own once its numeric sequences (``array.array`` in rclpy) are shown
as numpy arrays. rclpy's own ``serialize_message`` is slower and its buffer carries the
middleware's size estimate (4 bytes too long for a JointState), which rosbags refuses:
it is the fallback, cut to the length the message decodes to.

Each encoder checks its first message: rclpy must decode the bytes back to an equal
message, else the topic falls back for good (:attr:`Encoder.fallback` says why).
"""

import numpy as np

#: rclpy field type of a numeric sequence -> numpy dtype (rclpy holds them as
#: ``array.array``; fixed-size arrays are numpy arrays already).
_SEQUENCES = {'sequence<%s>' % k: v for k, v in (
    ('double', np.float64), ('float', np.float32), ('int8', np.int8), ('uint8', np.uint8),
    ('int16', np.int16), ('uint16', np.uint16), ('int32', np.int32),
    ('uint32', np.uint32), ('int64', np.int64), ('uint64', np.uint64))}


class _View:
    """A message's fields as rosbags reads them (attribute access only)."""

    def __init__(self, fields):
        self.__dict__.update(fields)


def _adapter(cls):
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
            sub = _adapter(get_message(typ if typ.count('/') == 2 else
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


class Encoder:
    """
    ``encoder(msg) -> bytes``: the CDR of one message type for a bag.

    :param typestore: the rosbags typestore of the bag (``Stores.ROS2_JAZZY``).
    :param msgtype: the ROS type name (``sensor_msgs/msg/JointState``).
    :param cls: the rclpy message class.
    """

    def __init__(self, typestore, msgtype, cls):
        """Prepare the rosbags route; the first message is checked (:meth:`__call__`)."""
        self.typestore, self.msgtype, self.cls = typestore, msgtype, cls
        self._adapt = _adapter(cls)
        self._checked = False
        #: ``''`` while the rosbags route serves, else why the rclpy route took over
        self.fallback = ''

    def __call__(self, msg):
        """Return the CDR bytes of ``msg`` (encapsulation header included)."""
        if self.fallback:
            return self._rclpy(msg)
        try:
            data = self.typestore.serialize_cdr(
                self._adapt(msg) if self._adapt is not None else msg, self.msgtype)
        except Exception as exc:  # noqa: BLE001 - a field rosbags cannot read: rclpy's way
            self.fallback = 'rosbags cannot serialise it: %s' % exc
            return self._rclpy(msg)
        if not self._checked:
            self._checked = True
            from rclpy.serialization import deserialize_message
            try:
                same = deserialize_message(bytes(data), self.cls) == msg
            except Exception as exc:  # noqa: BLE001 - bytes rclpy cannot read
                same, exc_text = False, str(exc)
            else:
                exc_text = 'decodes to another message'
            if not same:
                self.fallback = 'its CDR %s' % exc_text
                return self._rclpy(msg)
        return data

    def _rclpy(self, msg):
        """Serialise as rclpy does, cut to the length the message decodes to."""
        from rclpy.serialization import serialize_message
        data = serialize_message(msg)
        msgdef = self.typestore.get_msgdef(self.msgtype)
        _, pos = msgdef.deserialize_cdr_le(memoryview(data)[4:], 0, msgdef.cls,
                                           self.typestore)
        return data[:4 + pos]


def encoder(typestore, msgtype, cls):
    """Return the :class:`Encoder` of ``cls`` (type name ``msgtype``) for ``typestore``."""
    return Encoder(typestore, msgtype, cls)
