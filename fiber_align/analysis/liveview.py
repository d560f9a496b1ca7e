# SPDX-License-Identifier: Apache-2.0
"""
The pure parts of the Foxglove live view (``live_view`` node; docs/live_view.md).

No rclpy and no WebSocket here, so each part is unit-tested on its own:

- :func:`ros2msg_schema`: the ``ros2msg`` schema text of a ROS 2 message type, the
  ``.msg`` definition with its dependencies concatenated as ``foxglove_bridge`` does
  (depth first, each dependency once, after a line of 80 ``=`` and ``MSG: pkg/Name``);
- :class:`Decimator`: at most one UI frame per period of a channel, on a fixed phase;
- the 2-D power map of the rig's search: :mod:`fiber_align.analysis.powermap`;
- :func:`alignment_view`: the sequencer's ``alignment_state`` JSON as structured data;
- :func:`layout_topics`: the topics a Foxglove layout file reads;
- :class:`Listener`, the server's callbacks, and :class:`Tap`, one served topic.

SI units throughout (m, W, s); dBm only where a person reads it.
"""

import json
import math
import os
import re
import struct
import sys
import threading

#: ROS 2 primitive field types (no dependency).
PRIMITIVES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'))
#: The line before each dependency of a ``ros2msg`` schema (foxglove_bridge, rosbag2 mcap).
SEPARATOR = '=' * 80
_ARRAY = re.compile(r'\[[^\]]*\]$')


def split_type(name):
    """
    Return ``(package, message)`` of a type name.

    :param name: ``pkg/msg/Name`` or ``pkg/Name``.
    :raises ValueError: anything else.
    """
    parts = name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError('%r is not a message type (pkg/msg/Name)' % name)


def msg_dependencies(package, text):
    """
    Return the message types a ``.msg`` text uses, as sorted ``pkg/Name`` strings.

    :param package: the package of the message (a bare ``Name`` field type is its own).
    :param text: the ``.msg`` definition.
    """
    out = set()
    for line in text.splitlines():
        tokens = line.split('#', 1)[0].split()
        if len(tokens) < 2 or '=' in tokens[1] or (len(tokens) > 2 and tokens[2] == '='):
            continue                        # no field, or a constant (a primitive)
        typ = _ARRAY.sub('', tokens[0])
        base = typ.split('<=', 1)[0]        # a bounded string: string<=N
        if base in PRIMITIVES:
            continue
        out.add(typ.replace('/msg/', '/') if '/' in typ else '%s/%s' % (package, typ))
    return sorted(out)


def read_msg(package, name):
    """
    Return the ``.msg`` text of ``package/msg/name``.

    From the prefixes of ``AMENT_PREFIX_PATH`` (a sourced workspace), then this
    interpreter's prefix (the pip route: the ROS wheels install ``share/`` there).

    :raises FileNotFoundError: no prefix has it.
    """
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in prefixes + [sys.prefix]:
        path = os.path.join(prefix, 'share', package, 'msg', name + '.msg')
        if os.path.isfile(path):
            with open(path, encoding='utf-8') as f:
                return f.read()
    raise FileNotFoundError('%s/msg/%s.msg is in none of %s' % (
        package, name, ', '.join(prefixes + [sys.prefix])))


def ros2msg_schema(type_name, read):
    """
    Return the ``ros2msg`` schema text of ``type_name`` (str).

    The root definition, then each dependency not yet written, depth first in sorted
    order, each after a newline, a line of 80 ``=`` and a line ``MSG: pkg/Name``
    (foxglove_bridge's layout, which Foxglove's ROS 2 parser reads).

    :param type_name: ``pkg/msg/Name``.
    :param read: ``read(package, name) -> str``, the ``.msg`` text of a type.
    """
    seen = set()

    def walk(pkg, name, depth):
        if depth > 32:
            raise ValueError('message definition of %s nests too deep' % type_name)
        text = read(pkg, name)
        out = text
        for dep in msg_dependencies(pkg, text):
            if dep in seen:
                continue
            seen.add(dep)
            dpkg, dname = split_type(dep)
            out += '\n%s\nMSG: %s\n' % (SEPARATOR, dep) + walk(dpkg, dname, depth + 1)
        return out

    pkg, name = split_type(type_name)
    return walk(pkg, name, 0)


class Decimator:
    """
    One UI frame per ``1 / rate_hz`` at most, on a fixed phase (s of a monotonic clock).

    A frame may go up to a quarter period early (the polling timer's jitter does not
    drop one); a call late by several periods passes once and the phase moves on, so a
    stalled view never sends a burst to catch up.

    :param rate_hz: frames per second (> 0).
    """

    EARLY = 0.25        # the share of a period a frame may come early

    def __init__(self, rate_hz):
        """Pass the first call."""
        rate_hz = float(rate_hz)
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError('rate_hz must be > 0, got %r' % rate_hz)
        self.period_s = 1.0 / rate_hz
        self.next_s = None

    def due(self, now_s):
        """Return True when a frame may go at ``now_s`` (s), and take that slot."""
        if self.next_s is None:
            self.next_s = now_s + self.period_s
            return True
        if now_s < self.next_s - self.EARLY * self.period_s:
            return False
        if now_s >= self.next_s + self.period_s:    # late by more: a new phase
            self.next_s = now_s + self.period_s
        else:
            self.next_s += self.period_s
        return True

    def describe(self, rate_in_hz=None):
        """Return the decimation in words (the channel's metadata)."""
        text = 'newest message every %.6g s (at most %.6g Hz)' % (self.period_s,
                                                                  1.0 / self.period_s)
        if rate_in_hz:
            text += ' of a %.6g Hz topic' % rate_in_hz
        return text


def dbm(power_w):
    """Return a power (W) in dBm (``-inf`` for 0, NaN for a negative or NaN reading)."""
    p = float(power_w)
    if not p >= 0.0:
        return math.nan
    return 10.0 * math.log10(p / 1e-3) if p > 0 else -math.inf


def _payload(data):
    """Return ``(endianness prefix, payload memoryview)`` of a CDR message."""
    data = memoryview(data)
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError('not a CDR message (header %r)' % bytes(data[:4]))
    return ('<' if data[1] == 1 else '>'), data[4:]


def float64_value(data):
    """Return the value of a CDR ``std_msgs/Float64`` (bytes; SI as published)."""
    e, b = _payload(data)
    return struct.unpack_from(e + 'd', b, 0)[0]


def string_value(data):
    """Return the text of a CDR ``std_msgs/String`` (bytes)."""
    e, b = _payload(data)
    n = struct.unpack_from(e + 'I', b, 0)[0]
    if n < 1 or 4 + n > len(b):
        raise ValueError('truncated CDR string')
    return bytes(b[4:4 + n - 1]).decode('utf-8')


def joint_state(data):
    """
    Return ``(stamp_ns, positions)`` of a CDR ``sensor_msgs/JointState`` (bytes).

    ``positions``: the ``position`` array (m for the graph's bimorph tip), a tuple.
    """
    e, b = _payload(data)
    sec, nsec = struct.unpack_from(e + 'iI', b, 0)
    o = 8
    o += 4 + struct.unpack_from(e + 'I', b, o)[0]          # frame_id
    o = (o + 3) // 4 * 4
    names = struct.unpack_from(e + 'I', b, o)[0]
    o += 4
    for _ in range(names):
        o = (o + 3) // 4 * 4
        o += 4 + struct.unpack_from(e + 'I', b, o)[0]
    o = (o + 3) // 4 * 4
    n = struct.unpack_from(e + 'I', b, o)[0]
    o = (o + 4 + 7) // 8 * 8
    if o + 8 * n > len(b):
        raise ValueError('truncated CDR JointState')
    return sec * 1_000_000_000 + nsec, struct.unpack_from(e + '%dd' % n, b, o)


def joint_position(data):
    """Return ``position[0]`` of a CDR ``sensor_msgs/JointState`` (NaN when empty)."""
    pos = joint_state(data)[1]
    return pos[0] if pos else math.nan


#: The sequencer states in a fixed order (``state_index`` of :func:`alignment_view`).
STATES = ('IDLE', 'SEARCHING', 'PEAKING', 'TRACKING', 'HELD', 'RELEASING', 'FAULT')
_NUMBER_OR_NULL = {'type': ['number', 'null']}
#: JSON Schema of :func:`alignment_view` (the fields both sequencers report).
ALIGNMENT_SCHEMA = {
    'title': 'fiber_align.AlignmentState', 'type': 'object',
    'properties': dict(
        state={'type': 'string'}, state_index={'type': 'integer'},
        phase={'type': ['string', 'null']}, fault_reason={'type': ['string', 'null']},
        **{k: _NUMBER_OR_NULL for k in (
            'setpoint_m', 'aligned_position_m', 'setpoint_x_m', 'setpoint_y_m',
            'aligned_x_m', 'aligned_y_m', 'threshold_w', 'peak_samples', 'search_samples',
            'iterations', 'sample', 'sample_time_s')}),
}
#: JSON Schema of the optical power in dBm channel.
POWER_DBM_SCHEMA = {'title': 'fiber_align.OpticalPowerDbm', 'type': 'object',
                    'properties': {'power_w': {'type': 'number'},
                                   'power_dbm': {'type': ['number', 'null']}}}


def alignment_view(text):
    """
    Return the sequencer's ``alignment_state`` JSON as structured data (a dict).

    The sequencer's fields as they are, plus ``state_index`` (the state's place in
    :data:`STATES`, -1 if unknown) for a plot.

    :raises ValueError: ``text`` is not a JSON object.
    """
    d = json.loads(text)
    if not isinstance(d, dict):
        raise ValueError('alignment_state is not a JSON object')
    state = str(d.get('state', ''))
    d['state_index'] = STATES.index(state) if state in STATES else -1
    return d


def power_dbm_view(power_w):
    """Return the optical power channel's message: W and dBm (``None`` for no light)."""
    v = dbm(power_w)
    return {'power_w': float(power_w), 'power_dbm': v if math.isfinite(v) else None}


def json_bytes(obj):
    """Return ``obj`` as compact UTF-8 JSON (NaN and infinities as ``null``)."""
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v
    return json.dumps(clean(obj), separators=(',', ':')).encode('utf-8')


_PATH_TOPIC = re.compile(r'^(/[A-Za-z0-9_/]*[A-Za-z0-9_])')


def path_topic(path):
    """Return the topic of a Foxglove message path (``/x/displacement.position[0]``)."""
    m = _PATH_TOPIC.match(path.strip())
    if not m:
        raise ValueError('%r is not a message path (/topic.field...)' % path)
    return m.group(1)


def layout_topics(layout):
    """
    Return the set of topics a Foxglove layout reads (its panels' message paths and topics).

    Looks at every ``value`` of a plot path, every ``topicPath``, ``topic`` and the keys of
    a 3D panel's ``topics`` in ``configById``.
    """
    out = set()

    def walk(obj, key=None):
        if isinstance(obj, dict):
            for k, v in obj.items():
                if k == 'topics' and isinstance(v, dict):
                    out.update(t for t in v if t.startswith('/'))
                walk(v, k)
        elif isinstance(obj, list):
            for v in obj:
                walk(v, key)
        elif isinstance(obj, str) and key in ('value', 'topicPath', 'topic', 'messagePath') \
                and obj.startswith('/'):
            out.add(path_topic(obj))
    walk(layout.get('configById', {}))
    return out


class Listener:
    """The server's callbacks (its own threads): note which channels to send again."""

    def __init__(self):
        """Start with no channel to send again."""
        self.lock = threading.Lock()
        self.resend = set()

    def on_subscribe(self, client, channel):
        """Send ``channel`` again: a client subscribed."""
        with self.lock:
            self.resend.add(channel.id)

    def on_unsubscribe(self, client, channel):
        """Nothing to do."""

    def on_client_advertise(self, client, channel):
        """Nothing to do: the view takes no client's messages."""

    def on_client_unadvertise(self, client, client_channel_id):
        """Nothing to do."""

    def on_message_data(self, client, client_channel_id, data):
        """Nothing to do."""

    def take(self):
        """Return the ids of the channels to send again, and forget them."""
        with self.lock:
            out, self.resend = self.resend, set()
        return out


class Tap:
    """
    One served topic: its raw subscription, its channel, its decimation.

    A per-sample topic outside the power map is ``lazy``: subscribed only while a client
    watches it (``sub`` ``None`` meanwhile), so that the graph sends DDS nothing for a
    channel nobody shows (the array's 27 per-sample topics took 0.6 core of its
    process's time with the view and no client).
    """

    __slots__ = ('topic', 'msgtype', 'sub', 'channel', 'state', 'decimator', 'last',
                 'map_key', 'lazy')

    def __init__(self, topic, msgtype, sub, channel, state, decimator, map_key):
        """Keep the parts (``map_key``: its role in the power map, or ``None``)."""
        self.topic, self.msgtype, self.sub, self.channel = topic, msgtype, sub, channel
        self.state, self.decimator, self.map_key = state, decimator, map_key
        self.last = None
        self.lazy = not state and map_key is None and channel is not None

    def frames(self, got, resent, now):
        """
        Return the payloads to send this UI tick, of the messages ``got`` (``[(data, info)]``).

        A state topic: every message, or its last again when ``resent`` (a client just
        subscribed) and none came; a per-sample topic: its newest, when one came or it is
        ``resent`` and the decimator lets it through at ``now`` (s).
        """
        if got:
            self.last = got[-1][0]
        if self.state:
            return [d for d, _ in got] if got else [self.last] if resent and self.last else []
        if self.last is not None and (got or resent) and self.decimator.due(now):
            return [self.last]
        return []
