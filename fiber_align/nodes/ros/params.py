# SPDX-License-Identifier: Apache-2.0
"""
Parameters of the fiber_align nodes: defaults, descriptors, declarations and checks.

Defaults come from the ROS params files under ``config/`` only, through
:func:`node_defaults` (the graph's one merge law). Each node declares its parameters
from its table of :mod:`fiber_align.graph.ranges` (:func:`declare_row`), which the graph
checks a params file against before any process starts; a graph-wide value
(:data:`~fiber_align.graph.ranges.GRAPH_VALUES`: ``rate_hz``, ``sync_mode``,
``controller``, the setpoint limits, ...) is declared by :func:`declare_graph_values`,
read-only. Units are SI (m, m/s, V, s, Hz, W).
"""

import math

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import SetParametersResult

from fiber_align.config import config_path, ConfigError, flatten
from fiber_align.control.shaping import KINDS as SHAPING_KINDS
from fiber_align.design import design_dynamics, load_actuator
from fiber_align.graph.description import AREA_FILES, GRAPH_FILE
from fiber_align.graph.params import effective, merge_params, normalize
from fiber_align.graph.ranges import GRAPH_VALUES, SHAPING, si_range


#: The process-wide scheduling values a node of the control loop declares.
PRIORITY = ('cpu_idle_poll', 'lock_memory', 'publish_thread', 'realtime_priority')


def declare_graph_values(node, defaults, *names):
    """
    Declare the graph-wide values ``names`` read-only (``graph.ranges.GRAPH_VALUES``).

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
    Declare the sequencer's ``part_id``; return ``(status, power, peak) -> status``.

    The part the next ``align`` aligns (``ros2 param set`` before it), the last power (W)
    the sequencer stepped on and the highest since its previous status (W): the run
    catalogue's (docs/records.md), which so needs no 1 kHz subscription of its own.
    """
    declare(node, defaults, 'part_id', 'the part the next align aligns (text; "" = none)')
    return lambda status, power_w=None, peak_power_w=None: dict(
        status, part_id=str(node.get_parameter('part_id').value),
        power_w=None if power_w is None else float(power_w),
        peak_power_w=None if peak_power_w is None else float(peak_power_w))


def declare_row(node, defaults, table, name, read_only=True, choices=None):
    """
    Declare ``name`` with its description and range from ``table``; return its value.

    :param table: a node's table of :mod:`fiber_align.graph.ranges`,
        ``{name: (description, low, high)}`` (SI): the ranges the graph checks a params
        file against before any process starts.
    """
    text, lo, hi = table[name]
    return declare(node, defaults, name, text, lo, hi, read_only, choices)


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
    for name in SHAPING:
        out[name] = declare_row(node, defaults, SHAPING, name)
    for name, text in (
            ('delay_compensation', 'predict smooth references over the shaper delay plus '
             'one period (bool)'),
            ('design_file', 'actuator design params file (a name in config/ or a path) '
             'of the design model: mode frequency and gain')):
        out[name] = declare(node, defaults, name, text, read_only=True)
    return out


def design_model(shaping):
    """Return ``(omega_n_rad_s, alpha_m_per_v)`` of the design file in ``shaping``."""
    return design_dynamics(load_actuator(shaping['design_file']))


def declare_si(node, defaults, name, what, read_only=True):
    """
    Declare ``name`` with a unit and a range taken from the end of its name; return it.

    For the core parameters of a params file whose names carry their SI unit
    (``range_max_m``, ``search_timeout_s``, ``peak_drop_db``, ...).

    :param what: whose parameter it is, for the description (e.g. ``'sequencer'``).
    """
    row = si_range(name, defaults.get(name), what)
    if row:
        return declare(node, defaults, name, *row, read_only)
    return declare(node, defaults, name, '%s parameter (see its params file)' % what,
                   read_only=read_only)
