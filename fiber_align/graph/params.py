# SPDX-License-Identifier: Apache-2.0
"""
The parameters of the fiber_align graph: one law for merging params files (pure Python).

The graph's node names, the values its nodes share (:data:`SHARED`, one value for every
node that uses it, whatever section of a file sets it) and the merge of params files and
overrides into the one mapping every process reads (:func:`merge_params`). Used by
:mod:`fiber_align.graph.description` (launch file, demo, benches), by ``bringup`` and by each
node for its defaults. A user's params file or override is checked against the shipped
files first (:func:`check_user`): an unknown node or parameter, or a value of another
kind than its default, is refused with the closest known name.
"""

import difflib

import yaml

from fiber_align.config import ConfigError, read_yaml

PLANT = 'simulated_actuator'
COMPENSATOR = 'hysteresis_compensator'
CONTROLLER = 'fuzzy_pid_controller'
DRIVER = 'actuator_driver'
SCENARIO_RUNNER = 'scenario_runner'
SEQUENCER = 'alignment_sequencer'
RECORDER = 'bag_recorder'
LIFECYCLE_MANAGER = 'lifecycle_manager'
#: The Foxglove live view (``live:=true``, :mod:`fiber_align.graph.live`).
LIVE_VIEW = 'live_view'
#: The run catalogue's node (``catalog:=URL``, :mod:`fiber_align.graph.catalog`).
RUN_CATALOG = 'run_catalog'
#: How the graph pairs its messages (``sync_mode``): by arrival on the wall clock's
#: periods (``realtime``) or by index, deterministic (``lockstep``).
SYNC_MODES = ('realtime', 'lockstep')
#: Nodes that are lifecycle (managed) nodes, brought to active by ``lifecycle_manager``.
LIFECYCLE_NODES = (DRIVER,)
#: The nodes of one actuator's control loop (they share its rate, sync mode, setpoints).
LOOP_NODES = (PLANT, COMPENSATOR, CONTROLLER, DRIVER, SCENARIO_RUNNER, SEQUENCER)
#: The nodes of several axes: the rig's, the station's and the array's sequencer and optics, the
#: rig's amplifier. They run at the loops' rate, in their sync mode.
SEQUENCER_2D = 'alignment_sequencer_2d'
OPTICS_2D = 'simulated_optics_2d'
STATION_SEQUENCER = 'station_sequencer'
STATION_OPTICS = 'simulated_station_optics'
ARRAY_SEQUENCER = 'array_sequencer'
ARRAY_OPTICS = 'simulated_array_optics'
AMPLIFIER = 'mdt693b_driver'
AXES_NODES = (SEQUENCER_2D, OPTICS_2D, STATION_SEQUENCER, STATION_OPTICS, ARRAY_SEQUENCER,
              ARRAY_OPTICS, AMPLIFIER)
#: Reference shaping and the design model: the compensator's shaper and the controller's
#: reference model must be built from the same values (the composite loop's two halves).
SHAPING_KEYS = ('shaping', 'shaping_omega_n_rad_s', 'shaping_damping_ratio',
                'delay_compensation', 'delay_compensation_max_accel_m_per_s2', 'design_file')
#: Values the nodes of one graph must agree on: name -> the nodes that use it. A params
#: file (or override) may set one under ``/**`` or under any of those nodes; the latest
#: file that sets it decides it for all of them (:func:`lift_shared`), so no override of
#: one node can make two nodes disagree. Setting it differently for two nodes in one
#: file is refused.
SHARED = dict(
    # every node that declares the graph's rate or sync mode (a node of several axes too)
    [(k, LOOP_NODES + AXES_NODES + (RUN_CATALOG,)) for k in ('rate_hz', 'sync_mode')]
    + [(k, LOOP_NODES) for k in ('controller', 'setpoint_min_m', 'setpoint_max_m',
                                 'realtime_setpoint_accel_m_per_s2')]
    + [('realtime_setpoint_rate_m_per_s', LOOP_NODES + (SEQUENCER_2D, STATION_SEQUENCER,
                                                        ARRAY_SEQUENCER))]
    + [(k, (COMPENSATOR, CONTROLLER)) for k in SHAPING_KEYS]
    # no displacement sensor (the hardware graphs, graph/hardware.py, graph/hardware_rig.py)
    + [('sensorless', (COMPENSATOR, DRIVER, SEQUENCER, SEQUENCER_2D, AMPLIFIER))])


class GraphError(ConfigError):
    """A launch argument or option is wrong; the message names what and what is allowed."""


def normalize(value):
    """Return ``value`` with numeric lists as float lists (recursively)."""
    if isinstance(value, dict):
        return {k: normalize(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        if value and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                         for v in value):
            return [float(v) for v in value]
        return list(value)
    return value


def merge(a, b):
    """Return ``a`` updated recursively by ``b`` (mappings merge, other values replace)."""
    out = dict(a)
    for k, v in b.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


def nest(name, value):
    """Return ``{'a': {'b': value}}`` for the ROS dotted name ``a.b``."""
    out = value
    for part in reversed(name.split('.')):
        out = {part: out}
    return out


def _section_key(key, namespace):
    """Return a params-file key as a node name relative to ``namespace`` (or as it is)."""
    if key in ('/**', '**'):
        return '/**'
    k = key.lstrip('/')
    if namespace and k.startswith(namespace + '/'):
        k = k[len(namespace) + 1:]
    return k if '/' not in k and '*' not in k else key


def lift_shared(layer, where=''):
    """
    Move the :data:`SHARED` values of one params mapping into its ``/**`` section.

    :param layer: one params file's mapping (``{section: {'ros__parameters': ...}}``),
        sections keyed by node name (a namespaced key counts by its last part).
    :param where: the file or option, for the message.
    :returns: a new mapping: each shared value set under a node that uses it is removed
        there and set under ``/**`` (where every node of the graph reads it).
    :raises GraphError: one mapping sets a shared value differently for two sections.
    """
    out, lifted, origin = {}, {}, {}
    for key, sec in layer.items():
        node = '/**' if str(key) in ('/**', '**') else str(key).split('/')[-1]
        params = sec.get('ros__parameters') if isinstance(sec, dict) else None
        if not isinstance(params, dict):
            out[key] = sec
            continue
        keep = {}
        for name, value in params.items():
            if name in SHARED and (node == '/**' or node in SHARED[name]):
                if name in lifted and normalize(lifted[name]) != normalize(value):
                    raise GraphError(
                        '%s: %s is one value for %s, but it is %r under %s and %r under '
                        '%s: set it once (under /** or one node)'
                        % (where or 'params', name, ', '.join(SHARED[name]), lifted[name],
                           origin[name], value, key))
                lifted[name], origin[name] = value, key
            else:
                keep[name] = value
        out[key] = dict(sec, ros__parameters=keep)
    if lifted:
        out = merge(out, {'/**': {'ros__parameters': lifted}})
    return out


def wildcard_first(data):
    """
    Return the params mapping with its ``/**`` section first.

    rcl applies the sections of a params file that match a node in file order, a later
    one winning for the same name (seen with rclpy Jazzy): with ``/**`` last, its values
    beat the node's own section (``bag_recorder`` ran at ``realtime_priority`` 50 and
    ``diagnostics_period_s`` 0.5 instead of its 10 and 0.2). With ``/**`` first, a node's
    own value wins, as the ROS docs describe. (A ``-p`` on the command line counts as
    ``/**`` too: it loses to the node's section of the file, so the graph passes every
    value through the file.)
    """
    if '/**' not in data:
        return data
    out = {'/**': data['/**']}
    out.update((k, v) for k, v in data.items() if k != '/**')
    return out


def merge_params(files, overrides=None, namespace=''):
    """
    Merge ROS params files and overrides into one mapping keyed for ``namespace``.

    :param files: params file paths, in order (later ones win, key by key).
    :param overrides: ``{node or '/**': {name: value}}`` applied last; dotted names
        (``optics.gap_m``) are nested.
    :param namespace: the graph's namespace; node sections come out keyed
        ``/<namespace>/<node>`` (``<node>`` without one); ``/**`` and keys with
        wildcards or other namespaces stay as they are.
    :raises ConfigError: a file is missing or not a params mapping.
    """
    data = {}
    for f in files:
        for key, sec in lift_shared(read_yaml(f), str(f)).items():
            data = merge(data, {_section_key(str(key), namespace): sec})
    ov = {}
    for node, params in (overrides or {}).items():
        for name, value in params.items():
            ov = merge(ov, {_section_key(node, namespace):
                            {'ros__parameters': nest(name, value)}})
    data = wildcard_first(normalize(merge(data, lift_shared(ov, 'overrides'))))
    if not namespace:
        return data
    return {(k if k.startswith('/') else '/%s/%s' % (namespace, k)): v
            for k, v in data.items()}


def effective(params, node, namespace=''):
    """Return the parameters ``node`` gets from a merged mapping (``/**``, then its own)."""
    key = '/%s/%s' % (namespace, node) if namespace else node
    out = dict(params.get('/**', {}).get('ros__parameters', {}))
    out.update(params.get(key, {}).get('ros__parameters', {}))
    return out


def flat(params, prefix=''):
    """Return a nested ``ros__parameters`` mapping with ROS dotted names (``a.b``)."""
    out = {}
    for k, v in params.items():
        if isinstance(v, dict):
            out.update(flat(v, prefix + k + '.'))
        else:
            out[prefix + k] = v
    return out


def _closest(word, known):
    near = difflib.get_close_matches(word, list(known), n=1)
    return (' (did you mean %r?)' % near[0]) if near else ''


def _kind(v):
    if isinstance(v, bool):
        return 'bool'
    if isinstance(v, (int, float)):
        return 'number'
    return {str: 'string', list: 'list', tuple: 'list'}.get(type(v), type(v).__name__)


def check_names(data, known, where):
    """
    Raise :class:`GraphError` for a node or parameter ``data`` has and ``known`` has not.

    ``/**`` may set any parameter some node has; a node section only that node's or a
    ``/**`` one (graph-level values such as ``sync_mode``); a value must be of the kind of
    its default (bool, number, string, list).

    :param data: a params mapping (sections keyed by node, ``<axis>/<node>`` or a
        namespaced key: the last part counts).
    :param known: the merged shipped files.
    :param where: the file or option the values come from, for the message.
    """
    every = flat(known.get('/**', {}).get('ros__parameters', {}))
    per_node = {k.split('/')[-1]: dict(every, **flat(v.get('ros__parameters', {})))
                for k, v in known.items() if k != '/**' and isinstance(v, dict)}
    anywhere = set(every).union(*per_node.values()) if per_node else set(every)
    for key, sec in data.items():
        node = '/**' if str(key) in ('/**', '**') else str(key).split('/')[-1]
        if node != '/**' and node not in per_node:
            raise GraphError('%s: unknown node %r; known nodes: %s%s' % (
                where, key, ', '.join(sorted(per_node)), _closest(node, per_node)))
        if not isinstance(sec, dict) or not isinstance(sec.get('ros__parameters', {}), dict):
            raise GraphError('%s: section %r must hold ros__parameters: {name: value}'
                             % (where, key))
        defaults = {} if node == '/**' else per_node[node]
        for name, value in flat(sec.get('ros__parameters', {})).items():
            if name not in (anywhere if node == '/**' else defaults):
                raise GraphError('%s: unknown parameter %r of %s%s' % (
                    where, name, node, _closest(name, anywhere if node == '/**'
                                                else defaults)))
            if name in defaults and _kind(value) != _kind(defaults[name]):
                raise GraphError('%s: %s %s=%r must be a %s like its default %r' % (
                    where, node, name, value, _kind(defaults[name]), defaults[name]))


def check_user(shipped_files, user_files=(), overrides=None):
    """
    Check a user's params files and overrides against the shipped files (:func:`check_names`).

    :param shipped_files: the graph's own files (their nodes and parameters are known).
    :param user_files: the user's params files.
    :param overrides: the user's ``{node or '/**': {name: value}}`` (dotted names allowed).
    :raises GraphError: an unknown node or parameter, or a value of the wrong kind.
    """
    known = {}
    for f in shipped_files:
        known = merge(known, lift_shared(read_yaml(f), str(f)))
    for f in user_files:
        check_names(read_yaml(f), known, str(f))
    ov = {}
    for node, params in (overrides or {}).items():
        for name, value in params.items():
            ov = merge(ov, {node: {'ros__parameters': nest(name, value)}})
    check_names(ov, known, 'command line')


def parse_overrides(items, ov):
    """
    Return ``ov`` (``{node or '/**': {name: value}}``) updated by ``-p`` items (``bringup``).

    :param items: ``NODE:NAME:=VALUE`` strings (``NODE`` ``**`` = all nodes; VALUE YAML).
    :raises ConfigError: an item that is not ``NODE:NAME:=VALUE`` or not YAML.
    """
    # NODE may be <axis>/<node> (the rig): the description checks the names
    for item in items:
        node, sep1, rest = item.partition(':')
        name, sep2, value = rest.partition(':=')
        if not (node and sep1 and name and sep2):
            raise ConfigError('-p wants NODE:NAME:=VALUE, got %r' % item)
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ConfigError('-p %s: %r is not a YAML value' % (item, value)) from None
        ov.setdefault('/**' if node in ('**', '/**') else node, {})[name] = parsed
    return ov
