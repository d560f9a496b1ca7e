# SPDX-License-Identifier: Apache-2.0
"""
The graph's parameters as one params mapping: compose, check, namespace.

The per-area files, then ``config/fiber_align.yaml``, then the user's params files, then
the command-line overrides, merged in that order (later wins) into
``{node: {'ros__parameters': {...}}}`` with ROS-compatible types. Every node and
parameter name of a user file or override is checked against the shipped files, so a
typo is refused with the closest known name instead of being dropped without a word.
"""

import difflib

from fiber_align.config import ConfigError, config_path, read_yaml
from fiber_align.nodes.graph import AREA_FILES, GRAPH_FILE, lift_shared, merge, nest
from fiber_align.nodes.graph import normalize, wildcard_first
#: Sections of the shipped files that are not nodes of the graph (read by tools).
TOOL_SECTIONS = ('analyze', 'bringup')


def _flat(d, prefix=''):
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, prefix + k + '.'))
        else:
            out[prefix + k] = v
    return out


def shipped():
    """Return the merged mapping of the shipped files (the known nodes and parameters)."""
    data = {}
    for f in AREA_FILES + (GRAPH_FILE,):
        data = merge(data, lift_shared(read_yaml(config_path(f)), f))
    return data


def _closest(word, known):
    near = difflib.get_close_matches(word, list(known), n=1)
    return (' (did you mean %r?)' % near[0]) if near else ''


def _kind(v):
    if isinstance(v, bool):
        return 'bool'
    if isinstance(v, (int, float)):
        return 'number'
    if isinstance(v, str):
        return 'string'
    if isinstance(v, (list, tuple)):
        return 'list'
    return type(v).__name__


def _defaults(known, node):
    out = dict(_flat(known.get('/**', {}).get('ros__parameters', {})))
    out.update(_flat(known.get(node, {}).get('ros__parameters', {})))
    return out


def check_names(data, known, where):
    """
    Raise :class:`ConfigError` for a node or parameter ``data`` has and ``known`` has not.

    ``/**`` may set any parameter some node has; a node section only that node's or a
    ``/**`` one (graph-level values such as ``sync_mode``).

    :param where: the file or option the values come from, for the message.
    """
    nodes = {k.lstrip('/') for k in known if k != '/**'}
    every = set(_flat(known.get('/**', {}).get('ros__parameters', {})))
    per_node = {n: set(_flat(known.get(n, {}).get('ros__parameters', {}))) | every
                for n in nodes}
    anywhere = set().union(*per_node.values()) if per_node else set()
    for key, sec in data.items():
        node = key.split('/')[-1] if key != '/**' else '/**'
        if node != '/**' and node not in nodes:
            raise ConfigError('%s: unknown node %r; known nodes: %s%s'
                              % (where, key, ', '.join(sorted(nodes)), _closest(node, nodes)))
        if not isinstance(sec, dict) or not isinstance(sec.get('ros__parameters', {}), dict):
            raise ConfigError('%s: section %r must hold ros__parameters: {name: value}'
                              % (where, key))
        allowed = anywhere if node == '/**' else per_node[node]
        defaults = {} if node == '/**' else _defaults(known, node)
        for name, value in _flat(sec.get('ros__parameters', {})).items():
            if name not in allowed:
                raise ConfigError('%s: unknown parameter %r of %s%s'
                                  % (where, name, node, _closest(name, allowed)))
            if name in defaults and _kind(value) != _kind(defaults[name]):
                raise ConfigError('%s: %s %s=%r must be a %s like its default %r'
                                  % (where, node, name, value, _kind(defaults[name]),
                                     defaults[name]))


def compose(extra_files=(), overrides=None):
    """
    Return the merged params mapping ``{node: {ros__parameters: ...}}`` of the graph.

    :param extra_files: user params files applied after the shipped files.
    :param overrides: ``{node or '/**': {name: value}}`` applied last; dotted names
        (``optics.slot_position_m``) are nested.
    :raises ConfigError: a missing or malformed file, an unknown node or parameter.
    """
    known = shipped()
    data = dict(known)
    for f in extra_files:
        user = read_yaml(config_path(f))
        check_names(user, known, f)
        data = merge(data, lift_shared(user, f))
    ov = {}
    for node, params in (overrides or {}).items():
        for name, value in params.items():
            ov = merge(ov, {node: {'ros__parameters': nest(name, value)}})
    check_names(ov, known, 'command line')
    return wildcard_first(normalize(merge(data, lift_shared(ov, 'command line'))))


def node_params(data, node):
    """Return the effective parameters of ``node`` in a composed mapping (``/**`` first)."""
    out = dict(data.get('/**', {}).get('ros__parameters', {}))
    out.update(data.get(node, {}).get('ros__parameters', {}))
    return out


def namespaced(data, namespace):
    """Return the params mapping with node sections keyed ``/<namespace>/<node>``."""
    ns = namespace.strip('/')
    if not ns:
        return data
    return {(k if k.startswith('/') else '/%s/%s' % (ns, k)): v for k, v in data.items()}
