# SPDX-License-Identifier: Apache-2.0
"""
The Foxglove live view added to a described graph (pure Python: no rclpy).

:func:`with_live` takes any graph of :mod:`fiber_align.graph` (the 1-D graph, the rig,
the hardware bench) and returns it with one more process, ``live_view`` (executable
``live_view``, in the graph's namespace, its own process: never inside
``control_graph``), reading ``config/live_view.yaml`` then the graph's own values: the
topics the graph's nodes publish and read (:func:`graph_topics`, from the node registry
:data:`fiber_align.graph.registry.NODES`), the port and host, and on the rig the
power map over the 2-D sequencer's range. Used by the launch file (``live:=true
live_port:=8765 live_host:=127.0.0.1``) and ``bringup --live``.
"""

import dataclasses
import socket

from fiber_align.config import config_path
from fiber_align.graph import description as gd
from fiber_align.graph.params import GraphError, LIVE_VIEW, RECORDER, SEQUENCER_2D
from fiber_align.graph.registry import is_command

#: The view's params file (in ``config/``).
LIVE_FILE = 'live_view.yaml'
#: The keys of the 2-D sequencer's range (the power map's extent).
RANGE_KEYS = ('range_x_min_m', 'range_x_max_m', 'range_y_min_m', 'range_y_max_m')


def _specs(process, root):
    """
    Return ``(prefix, spec)`` of each node a process runs.

    ``spec``: the node's registry spec; ``prefix``: the part of its namespace below the
    graph's ``root`` (``x`` for the rig's axes, or ``''``).
    """
    if process.arguments[:1] == ('--nodes',):
        keys = process.arguments[1].split(',')
    elif process.executable in gd.NODES:
        keys = [process.executable]
    else:
        keys = list(process.nodes)
    ns = root if process.namespace is None else process.namespace
    own = ns[len(root):].strip('/') if ns.startswith(root) else ''
    out = []
    for k in keys:
        sub, _, base = k.rpartition('/')
        if base in gd.NODES:
            out.append(('/'.join(x for x in (own, sub) if x), gd.NODES[base]))
    return out


def graph_topics(graph):
    """
    Return the topics the graph's nodes publish and read (relative to its namespace).

    A node in a namespace below the graph's (the rig's axes) prefixes its topics with
    that part (``x/displacement``). In order of the processes, each topic once; never a
    command topic (:data:`~fiber_align.graph.registry.COMMANDS`): its one reader is the
    loop's, the view shows ``reference``.

    :param graph: a :class:`~fiber_align.graph.description.Graph` (or the rig's).
    """
    out = []
    for p in graph.processes:
        for prefix, spec in _specs(p, graph.namespace):
            for t in spec.publishes + spec.subscribes:
                out.append('%s/%s' % (prefix, t) if prefix else t)
    return tuple(t for t in dict.fromkeys(out) if not is_command(t))


def readers(graph):
    """
    Return ``{topic: [reader, ...]}`` of a described graph (topics relative to its namespace).

    The readers: every node's subscriptions (:data:`~fiber_align.graph.registry.NODES`),
    and the ``topics`` the recorder and the live view read (their parameters).
    """
    out = {}
    for p in graph.processes:
        for prefix, spec in _specs(p, graph.namespace):
            for t in spec.subscribes:
                out.setdefault('%s/%s' % (prefix, t) if prefix else t, []).append(
                    '/'.join(x for x in (prefix, spec.node) if x))
    for n in (RECORDER, LIVE_VIEW):
        if n in graph.nodes:
            for t in graph.node_params(n).get('topics', ()):
                out.setdefault(t.lstrip('/'), []).append(n)
    return out


def graph_published(graph):
    """Return the topics the graph's nodes publish (relative, as :func:`graph_topics`)."""
    out = []
    for p in graph.processes:
        for prefix, spec in _specs(p, graph.namespace):
            out += ['%s/%s' % (prefix, t) if prefix else t for t in spec.publishes]
    return tuple(dict.fromkeys(out))


def check_port(value):
    """Return ``live_port`` as an int in 1..65535, or raise :class:`GraphError`."""
    try:
        port = int(str(value).strip())
    except ValueError:
        raise GraphError('live_port %r is not allowed: a TCP port 1..65535' % (value,)) \
            from None
    if not 1 <= port <= 65535:
        raise GraphError('live_port %r is not allowed: a TCP port 1..65535' % (value,))
    return port


def check_endpoint(host, port):
    """
    Refuse (:class:`GraphError`, one line) a host that does not resolve or a port in use.

    Binds and closes a socket at ``host:port`` as the view will, before any process
    starts (the view refuses the same way itself when it loses a race).
    """
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise GraphError('live_host %r: cannot resolve it (%s)' % (host, exc)) from None
    family, kind, proto, _, addr = infos[0]
    s = socket.socket(family, kind, proto)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(addr)
    except OSError as exc:
        raise GraphError('live view ws://%s:%d: %s (another live view or program on that '
                         'port? choose live_port)' % (host, port, exc.strerror or exc)) \
            from None
    finally:
        s.close()


def with_live(graph, live=False, port='', host=''):
    """
    Return ``graph`` with the live view added when ``live``, else ``graph`` itself.

    :param live: bool or a launch-argument string (``'true'``).
    :param port: ``live_port`` (``''``: ``config/live_view.yaml``'s).
    :param host: ``live_host`` (``''``: ``config/live_view.yaml``'s).
    :raises GraphError: a bad value, or ``live_port``/``live_host`` without ``live``.
    """
    if not gd.parse_bool('live', live if live not in (None, '') else False):
        given = [k for k, v in (('live_port', port), ('live_host', host)) if v not in
                 (None, '')]
        if given:
            raise GraphError('%s: only with live:=true' % ', '.join(given))
        return graph
    over = {'topics': list(graph_topics(graph))}
    if port not in (None, ''):
        over['port'] = check_port(port)
    if host not in (None, ''):
        host = str(host).strip()
        if not host or any(c.isspace() for c in host):
            raise GraphError('live_host %r is not allowed: an address or host name' % host)
        over['host'] = host
    sequencer = [n for n in graph.nodes if n == SEQUENCER_2D]
    if sequencer:           # the rig: the power map over the sequencer's square
        seq = graph.node_params(SEQUENCER_2D)
        over.update(power_map=True, **{k: float(seq[k]) for k in RANGE_KEYS})
    overrides = {k: dict(v) for k, v in graph.overrides.items()}
    overrides[LIVE_VIEW] = dict(overrides.get(LIVE_VIEW, {}), **over)
    proc = gd.Process(LIVE_VIEW, LIVE_VIEW, (LIVE_VIEW,), node_name=LIVE_VIEW,
                      namespace=graph.namespace if graph.processes and
                      graph.processes[0].namespace is not None else None)
    return dataclasses.replace(
        graph, processes=graph.processes + (proc,),
        params_files=graph.params_files + (str(config_path(LIVE_FILE)),),
        overrides=overrides)


def live_settings(graph):
    """Return the live view's effective ``host`` and ``port`` in ``graph`` (or ``None``)."""
    if LIVE_VIEW not in graph.nodes:
        return None
    p = graph.node_params(LIVE_VIEW)
    return str(p['host']), int(p['port'])
