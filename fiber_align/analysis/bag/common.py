# SPDX-License-Identifier: Apache-2.0
"""
The graph's bag streams: message types, topic discovery, the decoded :class:`Stream`.

Topics are found by the last component of their name, so a graph run under any
namespace is read the same (``/rig1/displacement`` is the ``displacement`` stream).
Times: bag (receive) timestamps are int64 ns; header stamps are int64 ns. Values are SI
(m, m/s, V, W).
"""

from dataclasses import dataclass, field

import numpy as np

FLOAT64 = 'std_msgs/msg/Float64'
JOINT_STATE = 'sensor_msgs/msg/JointState'
MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'
CLOCK = 'rosgraph_msgs/msg/Clock'
DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'
STRING = 'std_msgs/msg/String'

#: The graph's streams: last name component -> message type.
GRAPH_TOPICS = {
    'setpoint': FLOAT64,
    'reference': FLOAT64,
    'displacement': JOINT_STATE,
    'feedforward_voltage': FLOAT64,
    'feedback_voltage': FLOAT64,
    'drive_voltage': FLOAT64,
    'optical_power': FLOAT64,
    'controller_state': MULTI_ARRAY,
    'diagnostics': DIAGNOSTICS,
    'clock': CLOCK,
    'alignment_state': STRING,
    'array_model': MULTI_ARRAY,
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


def storage_plugin(storage):
    """Return the rosbags StoragePlugin of a storage name (``mcap`` or ``sqlite3``)."""
    from rosbags.rosbag2 import StoragePlugin
    s = str(storage).lower()
    if s == 'mcap':
        return StoragePlugin.MCAP
    if s in ('sqlite3', 'sqlite', 'db3'):
        return StoragePlugin.SQLITE3
    raise ValueError('storage must be mcap or sqlite3, got %r' % storage)


def last_name(topic):
    """Return the last component of a topic name (``/ns/displacement`` -> ``displacement``)."""
    return topic.rstrip('/').rsplit('/', 1)[-1]


def discover(connections):
    """
    Map graph stream keys to connections, whatever the namespace.

    A topic matches a key when its last name component equals the key and its type is
    the key's type; without a ``setpoint`` topic, ``reference`` (what the graph records)
    is read as the setpoint. A ``std_msgs/String`` topic whose last name contains ``state`` or
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
    if 'setpoint' not in found and 'reference' in found:
        # the graph records ``reference``, the setpoint its loop accepted and followed
        # (the compensator is the only consumer of ``setpoint``): the r of every metric
        found['setpoint'] = found['reference']
    if 'alignment_state' not in found:
        for c in connections:
            nm = last_name(c.topic)
            if c.msgtype == STRING and ('state' in nm or 'alignment' in nm):
                found['alignment_state'] = c
                break
    return found
