# SPDX-License-Identifier: Apache-2.0
"""
Shared plumbing of the fiber_align nodes: QoS, defaults, parameters, health, setpoints.

Nothing here computes control: the nodes only turn messages into calls of the pure core
(:mod:`fiber_align.control`, :mod:`fiber_align.plant`) and back. Units are SI throughout
(m, m/s, V, s, Hz, W).

Defaults come from the ROS params files under ``config/`` only: a node declares each of
its parameters with the value found in its per-area file (e.g. ``plant.yaml``) overlaid
by the graph file ``fiber_align.yaml`` (its ``/**`` section, then the node's section),
which is exactly what ``bringup`` passes as ``--params-file`` arguments in that order.
"""

import json
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fiber_align.config import config_path, ConfigError, flatten, read_yaml
# The realtime setpoint trajectory lives in its own module; the nodes use it as c.<name>.
from fiber_align.nodes._trajectory import MAX_CATCH_UP  # noqa: F401
from fiber_align.nodes._trajectory import REALTIME_SETPOINT_RATE_M_PER_S  # noqa: F401
from fiber_align.nodes._trajectory import SetpointTrajectory  # noqa: F401

GRAPH_FILE = 'fiber_align.yaml'
PLANT_FILE = 'plant.yaml'

#: Seconds of history every per-sample publisher keeps (``displacement``,
#: ``feedforward_voltage``, ``feedback_voltage``, ``drive_voltage``, ``reference``,
#: ``optical_power``, ``controller_state``): a reader that falls behind (the recorder on a
#: loaded machine) catches up from the writer's history instead of losing samples, and
#: the writer never blocks on it (KEEP_LAST drops the oldest only after this long).
SAMPLE_HISTORY_S = 5.0
#: The same as a depth (messages) at the default 1 kHz; see :func:`sample_pub_qos`.
SAMPLE_DEPTH = 5000
#: Per-sample publishers: reliable, ``SAMPLE_HISTORY_S`` of history, transient local, so
#: a reader that matched the writer a moment after a sample was published (multi-process
#: lockstep start-up) still receives it: the first sample can no longer be lost in the
#: discovery race that used to stall one lockstep start in four.
CONTROL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Lockstep readers of the per-sample topics: reliable, deep and transient local (index
#: pairing needs every message, including one published before the match completed).
LOCKSTEP_QOS = CONTROL_QOS
#: ``/clock``: reliable publisher, matched by the best-effort subscriber of rclpy's
#: TimeSource; as deep as the control topics so a lagging recorder loses no tick.
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                       reliability=ReliabilityPolicy.RELIABLE)
DIAG_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE)
#: Realtime control readers of the per-sample topics: only the newest message matters,
#: so a node that fell behind skips stale samples instead of working through a backlog.
#: Reliable (matches the reliable publishers), volatile (no stale history on joining).
REALTIME_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
#: State topics published on change only (``drive_held``): a late joiner (e.g. a restarted
#: controller) gets the present state at once.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: The user's ``setpoint`` (one consumer: ``hysteresis_compensator``): reliable, volatile,
#: deep (every setpoint is checked, so each bad one is reported); a default rclpy or
#: ``ros2 topic pub`` publisher (reliable, volatile, depth 10) matches it.
SETPOINT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLE_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
#: ``reference`` as the realtime controller reads it: the newest accepted setpoint,
#: latched, so a restarted controller takes the present setpoint without a re-send.
REFERENCE_LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)

SYNC_MODES = ('realtime', 'lockstep')

#: DiagnosticStatus levels as ints (the message field is a byte).
OK, WARN, ERROR, STALE = 0, 1, 2, 3

#: Exit report prefix: each node prints one line ``FIBER_ALIGN_SENT {json}`` on exit with
#: the number of messages it published per topic; bringup collects them.
SENT_PREFIX = 'FIBER_ALIGN_SENT '


class LocalBus:
    """
    In-process delivery between the nodes of one process (the composed graph).

    ``rclpy`` has no intra-process transport: without this, a message between two nodes
    of one process is serialised, handed to DDS and delivered back through the executor.
    A node built with a bus publishes through :class:`Pub`, which hands every message to
    DDS (so outside subscribers, the recorder first, still receive every one) and then
    calls the in-process subscribers' callbacks directly, in the order they subscribed.
    A topic is delivered locally when a node of the process publishes it
    (:meth:`provide`, before the nodes are built); its in-process readers then create no
    DDS subscription, so an outside publisher on that topic is not heard by them (one
    writer per control topic). Names are the relative names the nodes use (one
    namespace per process; remapping is not supported in a composed process).
    """

    def __init__(self, topics=()):
        """Start with the relative names in ``topics`` delivered locally."""
        self.topics = set(topics)
        self._subs = {}
        self._last = {}

    def provide(self, *topics):
        """Mark ``topics`` (relative names) as published inside this process."""
        self.topics.update(topics)

    def local(self, topic):
        """Return True when ``topic`` is delivered inside this process."""
        return topic in self.topics

    def callbacks(self, topic):
        """Return the (live) list of in-process callbacks of ``topic``."""
        return self._subs.setdefault(topic, [])

    def latch(self, topic, msg):
        """Keep ``msg`` as the latched message of ``topic`` (given to late subscribers)."""
        self._last[topic] = msg

    def last(self, topic):
        """Return the latched message of ``topic`` or ``None``."""
        return self._last.get(topic)


class Pub:
    """A publisher that also delivers to the in-process subscribers of a :class:`LocalBus`."""

    __slots__ = ('pub', 'topic', 'topic_name', '_local', '_bus', '_latched')

    def __init__(self, node, msg_type, topic, qos, bus=None, latched=False):
        """Create the DDS publisher of ``topic`` (relative name) with ``qos``."""
        self.pub = node.create_publisher(msg_type, topic, qos)
        self.topic = topic
        self.topic_name = self.pub.topic_name
        self._bus = bus if bus is not None and bus.local(topic) else None
        self._local = self._bus.callbacks(topic) if self._bus is not None else ()
        self._latched = latched

    def publish(self, msg):
        """Publish ``msg`` to DDS, then to every in-process subscriber."""
        self.pub.publish(msg)
        if self._bus is not None:
            if self._latched:
                self._bus.latch(self.topic, msg)
            for cb in tuple(self._local):
                cb(msg)

    def get_subscription_count(self):
        """Return the DDS subscription count (in-process readers not included)."""
        return self.pub.get_subscription_count()

    def destroy(self, node):
        """Destroy the DDS publisher."""
        node.destroy_publisher(self.pub)


class LocalSub:
    """An in-process subscription of a :class:`LocalBus` (see :func:`subscription`)."""

    __slots__ = ('bus', 'topic', 'callback')

    def __init__(self, bus, topic, callback):
        """Register ``callback`` for ``topic``; a latched message is delivered at once."""
        self.bus, self.topic, self.callback = bus, topic, callback
        bus.callbacks(topic).append(callback)
        last = bus.last(topic)
        if last is not None:
            callback(last)

    def destroy(self):
        """Unregister the callback."""
        cbs = self.bus.callbacks(self.topic)
        if self.callback in cbs:
            cbs.remove(self.callback)


def subscription(node, msg_type, topic, callback, qos, bus=None):
    """
    Subscribe ``callback`` to ``topic`` (relative name) locally or through DDS.

    :returns: a :class:`LocalSub` when a node of this process publishes ``topic`` on
        ``bus``, else the rclpy Subscription.
    """
    if bus is not None and bus.local(topic):
        return LocalSub(bus, topic, callback)
    return node.create_subscription(msg_type, topic, callback, qos)


def unsubscribe(node, sub):
    """Destroy a subscription made by :func:`subscription`."""
    if isinstance(sub, LocalSub):
        sub.destroy()
    elif sub is not None:
        node.destroy_subscription(sub)


def _section(data, name):
    """Return ``data[name]['ros__parameters']`` (or ``{}``) for a params-file mapping."""
    for key in (name, '/' + name):
        sec = data.get(key)
        if isinstance(sec, dict) and isinstance(sec.get('ros__parameters'), dict):
            return dict(sec['ros__parameters'])
    return {}


def normalize(value):
    """
    Return ``value`` with ROS-compatible types: numeric lists become float lists.

    ROS parameters need homogeneous arrays; ``[0, 80.9]`` in a YAML file is made
    ``[0.0, 80.9]`` (recursively through mappings).
    """
    if isinstance(value, dict):
        return {k: normalize(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        if value and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                         for v in value):
            return [float(v) for v in value]
        return list(value)
    return value


def node_defaults(node_name, area_files=()):
    """
    Return the default parameter mapping of ``node_name``.

    :param node_name: node name as in the params files (no namespace).
    :param area_files: per-area params files (names in ``config/``), read in order.
    :returns: the merged ``ros__parameters``: ``rate_hz`` of the plant (the graph's
        control rate lives in ``plant.yaml``), then the area files, then ``fiber_align.yaml``
        (``/**`` section, then the node's section); later values win.
    :raises ConfigError: a file is missing or malformed.
    """
    out = {}
    plant = _section(read_yaml(config_path(PLANT_FILE)), 'simulated_actuator')
    if 'rate_hz' in plant:
        out['rate_hz'] = plant['rate_hz']
    for f in list(area_files) + [GRAPH_FILE]:
        data = read_yaml(config_path(f))
        if f == GRAPH_FILE:
            out.update(_section(data, '/**'))
        out.update(_section(data, node_name))
    return normalize(out)


def flatten_defaults(defaults, key):
    """Return the nested mapping ``defaults[key]`` as ROS dotted names (``key.a``)."""
    sub = defaults.get(key)
    if not isinstance(sub, dict):
        return {}
    return flatten(sub, key + '.')


def descriptor(description, lo=None, hi=None, read_only=False, step=0.0):
    """
    Return a ParameterDescriptor with a floating-point or integer range.

    :param description: text, stating the unit.
    :param lo: lower bound (``None``: no range).
    :param hi: upper bound.
    :param read_only: the parameter cannot change after start-up.
    """
    d = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if isinstance(lo, int) and isinstance(hi, int) and not isinstance(lo, bool):
            d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=int(step))]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi), step=step)]
    return d


def declare(node, defaults, name, description, lo=None, hi=None, read_only=False,
            choices=None):
    """
    Declare parameter ``name`` with its default from ``defaults``; return its value.

    :param choices: for string parameters, the allowed values (checked at start-up and
        by :func:`check_parameters`).
    :raises ConfigError: the default is missing from the params files.
    """
    if name not in defaults:
        raise ConfigError('parameter %r of node %s has no default in config/' %
                          (name, node.get_name()))
    value = defaults[name]
    if isinstance(value, int) and not isinstance(value, bool) and lo is not None \
            and isinstance(lo, float):
        value = float(value)
    desc = description
    if choices:
        desc = '%s (one of: %s)' % (description, ', '.join(choices))
    node.declare_parameter(name, value, descriptor(desc, lo, hi, read_only))
    v = node.get_parameter(name).value
    if choices and v not in choices:
        raise ConfigError('parameter %s=%r: must be one of %s' % (name, v, ', '.join(choices)))
    return v


def check_parameters(params, ranges, choices=None):
    """
    Check a parameter update against ranges; return a SetParametersResult.

    :param params: the rclpy Parameters being set.
    :param ranges: name -> (lo, hi) inclusive, SI units.
    :param choices: name -> allowed string values.
    """
    choices = choices or {}
    for p in params:
        if p.name in ranges and p.type_ in (p.Type.DOUBLE, p.Type.INTEGER):
            lo, hi = ranges[p.name]
            v = float(p.value)
            if not (math.isfinite(v) and lo <= v <= hi):
                return SetParametersResult(
                    successful=False,
                    reason='%s=%r is out of range [%g, %g]' % (p.name, p.value, lo, hi))
        if p.name in choices and p.value not in choices[p.name]:
            return SetParametersResult(
                successful=False,
                reason='%s=%r: must be one of %s'
                % (p.name, p.value, ', '.join(choices[p.name])))
    return SetParametersResult(successful=True)


def check_setpoint(value, lo, hi):
    """
    Return ``None`` when the setpoint ``value`` (m) is usable, else the reason (str).

    :param lo: lowest allowed setpoint (m).
    :param hi: highest allowed setpoint (m).
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        return 'setpoint %r is not a number' % (value,)
    if math.isnan(v):
        return 'setpoint is NaN'
    if math.isinf(v):
        return 'setpoint is %s' % ('+inf' if v > 0 else '-inf')
    if v < lo or v > hi:
        return 'setpoint %.6g m is outside [%.6g, %.6g] m' % (v, lo, hi)
    return None


class Health:
    """
    Publish the node's health on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray).

    One DiagnosticStatus named after the node's fully qualified name. ``warn``/``error``
    latch their level for ``hold_s`` seconds (wall time) so a short event is seen by
    every subscriber; ``set_values`` adds key/value pairs (units in the key names).
    """

    def __init__(self, node, period_s=0.5, hold_s=2.0, hardware_id='fiber_align'):
        """Create the publisher and a wall-clock timer (period in s)."""
        from rclpy.clock import Clock, ClockType
        self._node = node
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', DIAG_QOS)
        self._hold_s = float(hold_s)
        self._hw = hardware_id
        self._level = OK
        self._message = 'ok'
        self._until = 0.0
        self._base_level = OK
        self._base_message = 'ok'
        self.values = {}
        self.sent = 0
        self._timer = node.create_timer(float(period_s), self.publish,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def status(self, level, message):
        """Set the steady level (``OK``, ``WARN``, ``ERROR``: int) and message."""
        self._base_level, self._base_message = level, message

    def _latch(self, level, message):
        self._level, self._message = level, message
        self._until = time.monotonic() + self._hold_s
        self.publish()

    def warn(self, message):
        """Report a WARN now and keep it for ``hold_s`` s."""
        self._latch(WARN, message)

    def error(self, message):
        """Report an ERROR now and keep it for ``hold_s`` s."""
        self._latch(ERROR, message)

    def set_values(self, **values):
        """Set key/value pairs reported with the status."""
        self.values.update(values)

    def publish(self):
        """Publish the current status once (with the node's fresh ``sent.<topic>`` counts)."""
        counts = getattr(self._node, 'sent_counts', None)
        if counts is not None:
            self.values.update({'sent.' + k.lstrip('/'): v for k, v in counts().items()})
        if time.monotonic() < self._until and self._level >= self._base_level:
            level, message = self._level, self._message
        else:
            level, message = self._base_level, self._base_message
        st = DiagnosticStatus(level=bytes([level]), name=self._node.get_fully_qualified_name(),
                              message=message, hardware_id=self._hw)
        st.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in self.values.items()]
        arr = DiagnosticArray(status=[st])
        arr.header.stamp = self._node.get_clock().now().to_msg()
        try:
            self._pub.publish(arr)
            self.sent += 1
        except Exception:  # noqa: BLE001 - context already shut down at exit
            pass


def _fmt(v):
    if isinstance(v, float):
        return repr(v)
    return str(v)


def report_sent(node, counts):
    """
    Print the exit report of published message counts (one JSON line on stdout).

    :param counts: topic name -> number of messages published.
    """
    line = SENT_PREFIX + json.dumps({'node': node.get_fully_qualified_name(),
                                     'sent': dict(counts)})
    print(line, flush=True)
    sys.stdout.flush()


def stamp_to_s(stamp):
    """Return a builtin_interfaces/Time as float seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def s_to_stamp(t_s):
    """Return float seconds as a builtin_interfaces/Time (nanosecond exact for t >= 0)."""
    from builtin_interfaces.msg import Time
    ns = int(round(t_s * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


#: Periods of delay the realtime loop adds to the lockstep loop: the plant latches the
#: drive at its next tick (``simulated_actuator``), so the command computed from y_k
#: first acts over [t_k+1, t_k+2] instead of [t_k, t_k+1].
REALTIME_EXTRA_DELAY_PERIODS = 1


def extend_lead(obj, period_s, periods=REALTIME_EXTRA_DELAY_PERIODS):
    """
    Lengthen the delay compensation of ``obj`` by the realtime loop's extra delay.

    ``obj`` is a :class:`~fiber_align.control.feedforward.Feedforward` or a
    :class:`~fiber_align.control.shaping.ReferenceModel`; its ``lead``
    (:class:`~fiber_align.control.shaping.Lead`, if any) predicts smooth references over
    the shaper delay plus one period; in realtime the drive acts ``periods`` periods
    later still, so the horizon grows by ``periods * period_s`` (s). Returns ``obj``.
    """
    lead = getattr(obj, 'lead', None) if obj is not None else None
    if lead is not None:
        lead.lead_s += periods * float(period_s)
    return obj


def declare_graph(node, defaults, name, fallback, description, lo=None, hi=None,
                  read_only=False):
    """
    Declare a graph-level parameter whose default may not be in config/ yet; return it.

    The default comes from the params files when they set ``name`` and from
    ``fallback`` (a documented module constant) otherwise.
    """
    d = dict(defaults)
    d.setdefault(name, fallback)
    return declare(node, d, name, description, lo, hi, read_only)


def sample_qos(lockstep):
    """
    Return the subscription QoS of a per-sample topic for the sync mode.

    :param lockstep: True in lockstep (deep queue: index pairing needs every message),
        False in realtime (newest message only, see :data:`REALTIME_QOS`).
    """
    return LOCKSTEP_QOS if lockstep else REALTIME_QOS


def make_executor(realtime=False):
    """
    Return the executor for a node process.

    Realtime processes run on rclpy's C++ ``EventsExecutor`` when this rclpy has it (far
    less overhead per callback than the Python wait-set loop of the
    ``SingleThreadedExecutor``); others use the ``SingleThreadedExecutor``.
    """
    from rclpy.executors import SingleThreadedExecutor
    if realtime:
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except ImportError:
            pass
    return SingleThreadedExecutor()


def set_realtime_priority(priority):
    """
    Run the calling thread (the executor's) under ``SCHED_FIFO`` at ``priority``.

    Threads the executor starts afterwards inherit it; the DDS threads, created
    earlier with the nodes, keep the normal policy. This is what ros2_control's
    controller manager does: a 1 kHz loop on a general-purpose OS keeps its period
    against other load only at a realtime priority. Without the right to (not root,
    no ``rtprio`` limit, e.g. ``@realtime - rtprio 98`` in
    ``/etc/security/limits.conf``) it changes nothing and says why.

    :param priority: 1..99 (``SCHED_FIFO``), 0: leave the normal policy.
    :returns: a short text for the log and ``/diagnostics`` (``SCHED_FIFO 50``, or
        ``SCHED_OTHER (...)`` with the reason).
    """
    import os
    priority = int(priority)
    if priority <= 0:
        return 'SCHED_OTHER (realtime_priority 0)'
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:
        return 'SCHED_OTHER (SCHED_FIFO %d refused: %s)' % (priority, exc)
    return 'SCHED_FIFO %d' % priority


#: Errors of a node's construction that are bad input (a parameter of the wrong type or
#: out of its range, a broken config): one line and exit code 2, no traceback.
NODE_ERRORS = (ConfigError, ParameterException, ValueError, TypeError, KeyError)


def init(args=None):
    """
    Initialise rclpy with this process's own SIGINT and SIGTERM handlers; return the event.

    rclpy's handlers shut the context down at once, while the executor may still run a
    callback that then publishes on a dead context (``[FATAL] Exception in 'timers'
    callback`` at an ordinary stop). Here a signal only sets the returned event; the spin
    loop ends, and the nodes are destroyed and the context shut down in order. The
    handlers are installed whatever the inherited disposition (a background job of a
    non-interactive shell inherits SIGINT ignored).
    """
    import signal
    import threading

    import rclpy
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return stop


def refuse(name, exc):
    """Print one line for a node that cannot start (bad input); return exit code 2."""
    print('%s: error: %s' % (name, exc), file=sys.stderr, flush=True)
    return 2


def finish(nodes):
    """Print each node's exit report, destroy the nodes, shut rclpy down (idempotent)."""
    import rclpy
    for node in nodes if isinstance(nodes, (list, tuple)) else [nodes]:
        if node is None:
            continue
        if hasattr(node, 'sent_counts'):
            report_sent(node, node.sent_counts())
        node.destroy_node()
    rclpy.try_shutdown()


def spin(nodes, realtime=False, priority=0, stop=None):
    """
    Spin ``nodes`` (one node or a list) until the context shuts down.

    Ctrl-C, SIGTERM or ``rclpy.shutdown`` end it; the loop wakes at least every 0.1 s
    (wall) to notice a shutdown. Before spinning, the objects built so far are frozen
    out of the garbage collector's reach (``gc.freeze``): a full collection then walks
    only what the loop allocates, so it cannot stall a control period.

    :param realtime: choose the events executor when available (:func:`make_executor`).
    :param priority: ``SCHED_FIFO`` priority of the executor thread
        (:func:`set_realtime_priority`; 0: normal).
    :param stop: the event of :func:`init`; set, it ends the spin.
    """
    import gc
    nodes = list(nodes) if isinstance(nodes, (list, tuple)) else [nodes]
    # lockstep runs as fast as the messages go: a realtime policy there could only
    # starve the other processes of the graph
    priority = priority if realtime else 0
    sched = set_realtime_priority(priority)
    for node in nodes:
        if priority:
            log = node.get_logger().info if sched.startswith('SCHED_FIFO') \
                else node.get_logger().warn
            log('scheduling: %s' % sched)
        health = getattr(node, 'health', None)
        if health is not None:
            health.set_values(scheduling=sched)
    executor = make_executor(realtime)
    for node in nodes:
        executor.add_node(node)
    gc.collect()
    gc.freeze()
    try:
        while executor.context.ok() and not (stop is not None and stop.is_set()):
            executor.spin_once(timeout_sec=0.1)
    finally:
        for node in nodes:
            try:
                executor.remove_node(node)
            except Exception:  # noqa: BLE001 - context already shut down
                pass
        executor.shutdown(timeout_sec=1.0)


def node_priority(nodes):
    """Return the largest ``realtime_priority`` parameter of ``nodes`` (0 if none)."""
    out = 0
    for node in nodes if isinstance(nodes, (list, tuple)) else [nodes]:
        if node.has_parameter('realtime_priority'):
            out = max(out, int(node.get_parameter('realtime_priority').value))
    return out


def declare_priority(node, defaults):
    """Declare the read-only ``realtime_priority`` parameter (0..99); return it."""
    return declare(node, defaults, 'realtime_priority',
                   'SCHED_FIFO priority of the executor thread (1..99); 0: normal '
                   'scheduling (needs root or an rtprio limit; refused: a WARN)', 0, 99,
                   True)
