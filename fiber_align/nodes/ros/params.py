# SPDX-License-Identifier: Apache-2.0
"""
Parameters of the fiber_align nodes: defaults, descriptors, declarations and checks.

Defaults come from the ROS params files under ``config/`` only, through
:func:`node_defaults` (the graph's one merge law). Each node declares its parameters
from one table; a graph-wide value (:data:`GRAPH_VALUES`: ``rate_hz``, ``sync_mode``,
``controller``, the setpoint limits, ...) is declared by :func:`declare_graph_values`,
read-only, with its range written once here. Units are SI (m, m/s, V, s, Hz, W).
"""

import math

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import SetParametersResult

from fiber_align.config import config_path, ConfigError, flatten
from fiber_align.control.factory import CONTROLLERS
from fiber_align.control.shaping import KINDS as SHAPING_KINDS
from fiber_align.control.trajectory import REALTIME_SETPOINT_RATE_M_PER_S
from fiber_align.design import design_dynamics, load_actuator
from fiber_align.graph.description import AREA_FILES, GRAPH_FILE
from fiber_align.graph.params import effective, merge_params, normalize, SYNC_MODES


#: The graph-wide values: name -> (description, low, high, choices, fallback). Every
#: node that uses one declares it read-only through :func:`declare_graph_values`; the
#: fallback (``None``: none) serves a value the params files may not set.
GRAPH_VALUES = {
    'rate_hz': ('control rate (Hz)', 1.0, 20000.0, None, None),
    'sync_mode': ('sample pairing: index (lockstep) or latest (realtime)', None, None,
                  SYNC_MODES, None),
    'controller': ('control law (as in fiber-align simulate)', None, None, CONTROLLERS,
                   None),
    'sensorless': ('no displacement sensor: step once per setpoint, drive the '
                   'feedforward alone (bool)', None, None, None, None),
    'diagnostics_period_s': ('/diagnostics period (s)', 0.01, 60.0, None, None),
    'setpoint_min_m': ('lowest accepted setpoint (m)', -1e-3, 1e-3, None, None),
    'setpoint_max_m': ('highest accepted setpoint (m)', -1e-3, 1e-3, None, None),
    'realtime_setpoint_rate_m_per_s': (
        'realtime: rate limit of the setpoint trajectory (m/s); <= 0: none', -1.0, 10.0,
        None, REALTIME_SETPOINT_RATE_M_PER_S),
    'realtime_setpoint_accel_m_per_s2': (
        'realtime: acceleration limit of the setpoint trajectory (m/s^2); <= 0: none', -1.0,
        1e4, None, None),
    'cpu_idle_poll': ('with realtime_priority: hold /dev/cpu_dma_latency at 0 us while the '
                      'process runs, so idle CPUs poll instead of halting (bool; needs '
                      'root; refused: a WARN)', None, None, None, None),
    'lock_memory': ('with realtime_priority: lock the process memory in RAM (mlockall; '
                    'bool)', None, None, None, None),
    'realtime_priority': ('SCHED_FIFO priority of the executor thread (1..99); 0: normal '
                          'scheduling (needs root or an rtprio limit; refused: a WARN)', 0,
                          99, None, None),
    'publish_thread': ('realtime, composed: DDS publishes made by a thread of their own, '
                       'off the control thread (bool; docs/realtime.md)', None, None, None,
                       None),
}
#: The process-wide scheduling values a node of the control loop declares.
PRIORITY = ('cpu_idle_poll', 'lock_memory', 'publish_thread', 'realtime_priority')


def declare_graph_values(node, defaults, *names):
    """
    Declare the graph-wide values ``names`` read-only (:data:`GRAPH_VALUES`).

    :returns: ``{name: value}`` of ``names`` (SI).
    """
    out = {}
    for name in names:
        text, lo, hi, choices, fallback = GRAPH_VALUES[name]
        d = defaults
        if fallback is not None and name not in d:
            d = dict(d, **{name: fallback})
        out[name] = declare(node, d, name, text, lo, hi, True, choices)
    return out


def node_defaults(node_name, area_files=()):
    """
    Return the default parameter mapping of ``node_name``.

    Exactly what the node gets in a graph without user files: the shipped per-area files
    (:data:`fiber_align.graph.description.AREA_FILES`, then ``area_files`` the graph does not
    list), then ``fiber_align.yaml``, merged by the graph's one law
    (:func:`fiber_align.graph.params.merge_params`: values the nodes share, such as
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


def declare_part(node, defaults):
    """
    Declare the sequencer's ``part_id``; return ``(status, power_w) -> status with both``.

    The part the next ``align`` aligns (``ros2 param set`` before it) and the last power
    (W) the sequencer stepped on: the run catalogue's (docs/records.md).
    """
    declare(node, defaults, 'part_id', 'the part the next align aligns (text; "" = none)')
    return lambda status, power_w=None: dict(
        status, part_id=str(node.get_parameter('part_id').value),
        power_w=None if power_w is None else float(power_w))


def declare_rows(node, rows):
    """
    Declare a table of parameters; return the ranges of the writable ones.

    :param rows: ``(name, default, description, lo, hi, read_only, choices)`` each.
    :returns: ``{name: (lo, hi)}`` of the rows not read-only (for :func:`check_parameters`).
    """
    ranges = {}
    for name, v, text, lo, hi, read_only, choices in rows:
        declare(node, {name: v}, name, text, lo, hi, read_only, choices)
        if not read_only:
            ranges[name] = (lo, hi)
    return ranges


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


def declare_shaping(node, defaults):
    """
    Declare the reference shaping and design-model parameters (read-only); return them.

    The compensator's shaper and the controller's reference model are built from these
    values; the graph keeps them one value for both (:data:`fiber_align.graph.params.SHARED`).

    :returns: ``{name: value}`` of :data:`fiber_align.graph.params.SHAPING_KEYS` (SI units).
    """
    out = {'shaping': declare(node, defaults, 'shaping',
                              'resonance suppression of the reference', read_only=True,
                              choices=SHAPING_KINDS)}
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
