# SPDX-License-Identifier: Apache-2.0
"""
An rclpy message's CDR for a bag without DDS (:func:`encoder`); a topic recorded off the bus.

:class:`BusTopic` records one topic of ``control_graph``'s in-process bus.

The in-process recorder (``bag_recorder`` hosted in ``control_graph``) receives the
Python message objects of its process's nodes, not DDS's bytes. rosbags' generated
serialisers read the fields by attribute, so they serialise an rclpy message as they
would one of their own once its numeric sequences (``array.array`` in rclpy) are shown
as numpy arrays. rclpy's own ``serialize_message`` is slower and its buffer carries the
middleware's size estimate (4 bytes too long for a JointState), which rosbags refuses:
it is the fallback, cut to the length the message decodes to.

Faster than both, for the types a control period publishes (numbers, strings, their
sequences and nested messages: ``Float64``, ``JointState``, ``Float64MultiArray``):
:func:`~fiber_align.analysis.bag.packer.packer`, the type's fields packed in order with
:mod:`struct` by a plan made once. A recorder writes thousands of messages a second
from the control thread's slack, so this is the period's cost: Float64 1.2,
Float64MultiArray 3.4, JointState 6.9 us a message here, against 2.4, 7.8 and 15.7 us
through rosbags.

Each encoder checks its first message: the packed bytes must equal rosbags' (else the
packer is dropped for the type), and rclpy must decode the bytes back to the same
message (field by field, a NaN equal to a NaN), else the topic falls back for good
(:attr:`Encoder.fallback` says why).
"""

import time

from fiber_align.analysis.bag.packer import adapter, packer, same as equal
from fiber_align.graph.endpoints import type_name
from fiber_align.nodes.ros.bus import LocalSub


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
        self._adapt = adapter(cls)
        self._pack = packer(cls)
        self._checked = False
        #: ``''`` while the rosbags route serves, else why the rclpy route took over
        self.fallback = ''

    def warm(self):
        """Do the routes' first use on a default message (7-23 ms a type), not the check."""
        msg = self.cls()
        try:
            data = self.typestore.serialize_cdr(
                self._adapt(msg) if self._adapt is not None else msg, self.msgtype)
            if self._pack is not None:
                self._packed(msg)
            from rclpy.serialization import deserialize_message
            deserialize_message(bytes(data), self.cls)
        except Exception:  # noqa: BLE001 - warming only: the first message decides
            pass

    def __call__(self, msg):
        """Return the CDR bytes of ``msg`` (encapsulation header included)."""
        if self.fallback:
            return self._rclpy(msg)
        if self._checked and self._pack is not None:
            return self._pack(msg)
        try:
            data = self.typestore.serialize_cdr(
                self._adapt(msg) if self._adapt is not None else msg, self.msgtype)
        except Exception as exc:  # noqa: BLE001 - a field rosbags cannot read: rclpy's way
            self.fallback = 'rosbags cannot serialise it: %s' % exc
            return self._rclpy(msg)
        if not self._checked:
            self._checked = True
            if self._pack is not None and self._packed(msg) != bytes(data):
                self._pack = None           # rosbags' bytes are the reference
            from rclpy.serialization import deserialize_message
            try:
                # NaN-aware: a NaN (a derivative's first sample) is not equal to itself,
                # and == took it for another message
                same = equal(deserialize_message(bytes(data), self.cls), msg)
            except Exception as exc:  # noqa: BLE001 - bytes rclpy cannot read
                same, exc_text = False, str(exc)
            else:
                exc_text = 'decodes to another message'
            if not same:
                self.fallback = 'its CDR %s' % exc_text
                return self._rclpy(msg)
        return data

    def _packed(self, msg):
        try:
            return self._pack(msg)
        except Exception:  # noqa: BLE001 - a value the plan cannot pack: rosbags' way
            return None

    @property
    def route(self):
        """Return how it encodes: ``packer``, ``rosbags`` or ``rclpy`` (after a fallback)."""
        return 'rclpy' if self.fallback else 'packer' if (
            self._pack is not None) else 'rosbags'

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


class BusTopic:
    """
    One topic recorded in-process: its bus subscription, encoder and bag connection.

    A recorder hosted in ``control_graph`` takes the messages its process's nodes
    publish from the :class:`~fiber_align.nodes.ros.bus.LocalBus` as objects and makes
    their CDR here: nothing of it goes through DDS.

    :param bus: the process's bus.
    :param topic: the topic's full name.
    :param sink: the bag (:class:`fiber_align.analysis.bag.sink.Sink`): ``put``,
        ``flush_due``.
    :param stop: called when a write failed (a full disk).
    :param log: the node's logger.
    """

    def __init__(self, bus, topic, sink, stop, log):
        """Subscribe on ``bus``; a type the bus knows gets its encoder now, warmed."""
        self.topic, self.sink, self.stop, self.log = topic, sink, stop, log
        self.encode = None
        self.write = None
        self.done = False
        cls = getattr(bus, 'types', {}).get(topic)
        if cls is not None:
            self.encode = encoder(sink.typestore, type_name(cls), cls)
            self.encode.warm()
        self.sub = LocalSub(bus, topic, self._on_message)

    def _on_message(self, msg):
        if self.done:
            return
        if self.write is None:
            msgtype = type_name(type(msg))
            if self.encode is None or self.encode.cls is not type(msg):
                self.encode = encoder(self.sink.typestore, msgtype, type(msg))
            self.write = self.sink.put(self.topic, msgtype)
            self.log.info('recording %s (%s) in-process' % (self.topic, msgtype))
        # written at once, a few microseconds; so is the chunk close when due: its cost
        # grows with the chunk, so it is kept small and regular (deferred to a later
        # slack it only grew)
        if not self.write(time.time_ns(), self.encode(msg)) or not self.sink.flush_due():
            self.stop()

    def destroy(self):
        """Leave the bus; no message is written after this."""
        self.done = True
        self.sub.destroy()
