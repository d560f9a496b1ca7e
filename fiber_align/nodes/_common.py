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

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import SetParametersResult

from fiber_align.config import config_path, ConfigError, flatten
from fiber_align.design import design_dynamics, load_actuator
# The transport (QoS, in-process delivery) and the process runtime live in modules of
# their own; the nodes use them as c.<name>.
from fiber_align.nodes._runtime import finish, guard_change_state, init  # noqa: F401
from fiber_align.nodes.graph import AREA_FILES, effective, GRAPH_FILE, merge_params
from fiber_align.nodes.graph import SHARED  # noqa: F401 - values the nodes share
from fiber_align.nodes.graph import normalize  # noqa: F401 - one law for params types
from fiber_align.nodes._runtime import make_executor  # noqa: F401
from fiber_align.nodes._runtime import NODE_ERRORS, node_priority, refuse  # noqa: F401
from fiber_align.nodes._runtime import report_sent, run_node, SENT_PREFIX  # noqa: F401
from fiber_align.nodes._runtime import set_realtime_priority, spin  # noqa: F401
from fiber_align.nodes._transport import CLOCK_QOS, CONTROL_QOS, DAC_QOS  # noqa: F401
from fiber_align.nodes._transport import DIAG_QOS  # noqa: F401
from fiber_align.nodes._transport import LATCHED_QOS, LocalBus, LocalSub  # noqa: F401
from fiber_align.nodes._transport import LOCKSTEP_QOS, Pub, REALTIME_QOS  # noqa: F401
from fiber_align.nodes._transport import REFERENCE_LATCHED_QOS, sample_qos  # noqa: F401
from fiber_align.nodes._transport import SAMPLE_DEPTH, SETPOINT_QOS  # noqa: F401
from fiber_align.nodes._transport import slack_of  # noqa: F401
from fiber_align.nodes._transport import subscription, unsubscribe  # noqa: F401
# The realtime setpoint trajectory lives in its own module; the nodes use it as c.<name>.
from fiber_align.nodes._trajectory import DRIVE_STALE_PERIODS, MAX_CATCH_UP  # noqa: F401
from fiber_align.nodes._trajectory import REALTIME_SETPOINT_RATE_M_PER_S  # noqa: F401
from fiber_align.nodes._trajectory import SetpointTrajectory, stamp_ns  # noqa: F401


SYNC_MODES = ('realtime', 'lockstep')

#: DiagnosticStatus levels as ints (the message field is a byte).
OK, WARN, ERROR, STALE = 0, 1, 2, 3


def node_defaults(node_name, area_files=()):
    """
    Return the default parameter mapping of ``node_name``.

    Exactly what the node gets in a graph without user files: the shipped per-area files
    (:data:`fiber_align.nodes.graph.AREA_FILES`, then ``area_files`` the graph does not
    list), then ``fiber_align.yaml``, merged by the graph's one law
    (:func:`fiber_align.nodes.graph.merge_params`: values the nodes share, such as
    ``rate_hz`` or the shaping, come out once under ``/**``), ``/**`` then the node's
    section.

    :param node_name: node name as in the params files (no namespace).
    :param area_files: extra params files (names in ``config/``) of this node.
    :raises ConfigError: a file is missing or malformed.
    """
    names = AREA_FILES + tuple(f for f in area_files if f not in AREA_FILES) + (GRAPH_FILE,)
    return normalize(effective(merge_params([config_path(f) for f in names]), node_name))


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

    def __init__(self, node, period_s=0.5, hold_s=2.0, hardware_id='fiber_align', slack=None):
        """
        Create the publisher and a wall-clock timer (period in s).

        :param slack: a :class:`~fiber_align.nodes._cycle.Slack`: the periodic report
            then runs right after a cycle of the node's process, never just before one.
        """
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
        #: a :class:`~fiber_align.nodes._cycle.CycleStats` whose window is reported with
        #: every publish (per-sample nodes set it), or ``None``
        self.cycle = None
        self._timer = node.create_timer(
            float(period_s), self.publish if slack is None else lambda: slack.submit(self.publish),
            clock=Clock(clock_type=ClockType.STEADY_TIME))

    def status(self, level, message):
        """
        Set the steady level (``OK``, ``WARN``, ``ERROR``: int) and message.

        A status at least as severe as a latched event replaces it: the newer news wins
        (a device lost right after a refused configure reported the refusal for 2 s).
        """
        self._base_level, self._base_message = level, message
        if level >= self._level:
            self._until = 0.0

    @property
    def message(self):
        """Steady status text (str) of the node."""
        return self._base_message

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
        if self.cycle is not None:
            self.values.update(self.cycle.window(time.monotonic_ns()))
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


def declare_priority(node, defaults):
    """Declare the read-only ``realtime_priority`` (0..99) and ``lock_memory``; return it."""
    declare(node, defaults, 'lock_memory', 'with realtime_priority: lock the process '
            'memory in RAM (mlockall; bool)', read_only=True)
    return declare(node, defaults, 'realtime_priority',
                   'SCHED_FIFO priority of the executor thread (1..99); 0: normal '
                   'scheduling (needs root or an rtprio limit; refused: a WARN)', 0, 99,
                   True)


def declare_sync(node, defaults):
    """
    Declare the read-only ``sync_mode``, ``diagnostics_period_s``, ``realtime_priority``.

    :returns: ``(lockstep, diagnostics_period_s)``: True in lockstep; the period (s).
    """
    lockstep = declare(node, defaults, 'sync_mode', 'sample pairing: index (lockstep) or '
                       'latest (realtime)', read_only=True, choices=SYNC_MODES) == 'lockstep'
    diag = declare(node, defaults, 'diagnostics_period_s', '/diagnostics period (s)', 0.01,
                   60.0, True)
    declare_priority(node, defaults)
    return lockstep, diag


#: Reference shaping laws (``shaping`` parameter).
SHAPING = ('none', 'zv', 'zvd')


def declare_shaping(node, defaults):
    """
    Declare the reference shaping and design-model parameters (read-only); return them.

    The compensator's shaper and the controller's reference model are built from these
    values; the graph keeps them one value for both (:data:`graph.SHARED`).

    :returns: ``{name: value}`` of :data:`graph.SHAPING_KEYS` (SI units).
    """
    out = {'shaping': declare(node, defaults, 'shaping',
                              'resonance suppression of the reference', read_only=True,
                              choices=SHAPING)}
    for name, text, lo, hi in (
            ('shaping_omega_n_rad_s', 'mode to suppress (rad/s); <= 0: the design model',
             -1.0, 1e6),
            ('shaping_damping_ratio', 'damping ratio of that mode (1)', 0.0, 0.999),
            ('delay_compensation_max_accel_m_per_s2',
             'growth limit of the predicted reference rate (m/s^2)', 0.0, 1e6),
            ('delay_compensation', 'predict smooth references over the shaper delay plus '
             'one period (bool)', None, None),
            ('design_file', 'actuator design params file (a name in config/ or a path) '
             'of the design model: mode frequency and gain', None, None)):
        out[name] = declare(node, defaults, name, text, lo, hi, True)
    return out


def design_model(shaping):
    """Return ``(omega_n_rad_s, alpha_m_per_v)`` of the design file in ``shaping``."""
    return design_dynamics(load_actuator(shaping['design_file']))


#: Unit and allowed range of a parameter, by the end of its name (SI; checked in order).
SI_SUFFIXES = (
    ('_m_per_s', 'm/s', -1.0, 1.0), ('_rad_s', 'rad/s', 0.0, 1e7), ('_hz', 'Hz', 0.0, 1e6),
    ('_db', 'dB', -300.0, 300.0), ('_w', 'W', 0.0, 100.0), ('_m', 'm', -1e-2, 1e-2),
    ('_s', 's', 0.0, 3600.0), ('_samples', 'samples', 0, 10_000_000),
    ('_sigma', 'standard deviations', 0.0, 1e6), ('_refits', 'count', 0, 1000))


def declare_si(node, defaults, name, what, read_only=True):
    """
    Declare ``name`` with a unit and a range taken from the end of its name; return it.

    For the core parameters of a params file whose names carry their SI unit
    (``range_max_m``, ``search_timeout_s``, ``peak_drop_db``, ...).

    :param what: whose parameter it is, for the description (e.g. ``'sequencer'``).
    """
    for suffix, unit, lo, hi in SI_SUFFIXES:
        if name.endswith(suffix) and not isinstance(defaults.get(name), bool):
            return declare(node, defaults, name, '%s parameter (%s)' % (what, unit), lo, hi,
                           read_only)
    return declare(node, defaults, name, '%s parameter (see its params file)' % what,
                   read_only=read_only)
