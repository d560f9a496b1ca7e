# SPDX-License-Identifier: Apache-2.0
"""
A graph's params checked before any process starts: ranges, drive limits (pure).

:func:`check_graph` (called by :func:`fiber_align.graph.arguments.describe`: the launch
file and ``bringup``) refuses, in one line, a value out of the range its node declares
(:mod:`fiber_align.graph.ranges`, the nodes' own tables), the drive limits a driver could
not configure with (the field limits: :func:`~fiber_align.hardware.driver_session.refusal`)
and a ``v_max`` above the amplifier's limit: the simulated amplifier's (``simulated_actuator``
``v_min``, ``v_max``) or the MDT693B's limit switch (``device_limit_v``, else its highest
setting).
"""

from fiber_align.config import config_path, load_params
from fiber_align.control import driver_axes as da
from fiber_align.graph.machines import MACHINES
from fiber_align.graph.params import DRIVER, effective, GraphError, merge, merge_params, PLANT
from fiber_align.graph.ranges import DRIVERS, range_refusal, SEQUENCERS
from fiber_align.graph.registry import AREA_FILES, GRAPH_FILE
from fiber_align.hardware.driver_session import refusal
from fiber_align.hardware.mdt693b import LIMIT_SWITCHES_V
from fiber_align.hardware.mdt693b_session import backend_defaults, DEVICE_KEYS


def core_keys(node, params):
    """
    Return the core parameter names a sequencer ``node`` declares by unit (or ``()``).

    Its ``machine`` (in ``params``) names the core and so its params file and section.
    """
    if node not in SEQUENCERS or params.get('machine') not in MACHINES:
        return ()
    m = MACHINES[params['machine']].module
    return tuple(load_params(m.CONFIG_FILE, m.CONFIG_NODE))


def axis_params(p, axis):
    """Return one axis's driver parameters (its limits, the shared keys) of a driver's ``p``."""
    out = {k: p[k] for k in da.SHARED_KEYS + da.LIMIT_KEYS if k in p}
    sec = p.get(axis) if axis else None
    for k in da.AXIS_KEYS:
        v = (sec or {}).get(k, p.get(k))
        if v is not None:
            out[k] = v
    return out


def drive_refusal(p, amplifier, label):
    """
    Return ``None`` or why a driver could not drive its axes (one line).

    :param p: the driver's effective parameters (nested ``<axis>`` sections).
    :param amplifier: ``(v_min, v_max)`` (V) of the simulated amplifier of its axes, or
        ``None`` (the MDT693B backend: its limit switch counts).
    :param label: the node as the line names it.
    """
    axes = {str(a): axis_params(p, str(a)) for a in p.get('axes') or ['']}
    device = p.get('backend') == 'mdt693b'
    why = refusal(axes, {k: p.get(k) for k in DEVICE_KEYS} if device else None,
                  p.get('sync_mode') == 'lockstep')
    if why:
        return '%s: %s' % (label, why)
    for a, q in axes.items():
        name = '%s.v_max' % a if a else 'v_max'
        if device:
            limit = float(p.get('device_limit_v') or 0.0) or max(LIMIT_SWITCHES_V)
            if float(q['v_max']) > limit:
                return ("%s: %s=%g V is above the amplifier's limit %g V (the MDT693B's "
                        '%s)' % (label, name, q['v_max'], limit,
                                 'device_limit_v' if p.get('device_limit_v')
                                 else 'highest limit switch'))
        elif amplifier is not None:
            lo, hi = amplifier
            if float(q['v_max']) > hi or float(q['v_min']) < lo:
                return ("%s: %s=%g V, v_min=%g V: outside the amplifier's limits [%g, %g] V "
                        '(%s v_min, v_max: the simulated amplifier)'
                        % (label, name, q['v_max'], q['v_min'], lo, hi, PLANT))
    return None


def driver_defaults(backend):
    """
    Return the defaults a driver node starts from (as the node: ``node_defaults``).

    Every driver node (``actuator_driver``, the rig's ``mdt693b_driver``) reads
    ``actuator_driver``'s shipped values, and with the ``mdt693b`` backend the device's
    (:func:`~fiber_align.hardware.mdt693b_session.backend_defaults`).
    """
    d = effective(merge_params([config_path(f) for f in AREA_FILES + (GRAPH_FILE,)]), DRIVER)
    if backend:
        d = dict(d, **backend_defaults(backend, load_params('hardware.yaml', DRIVER),
                                       load_params('hardware.yaml', '/**')['port']))
    return d


def check_graph(graph):
    """
    Raise :class:`~fiber_align.graph.params.GraphError` for a value no node would take.

    Every node of every process: each value against its declared range
    (:func:`range_refusal`); each driver's limits (:func:`drive_refusal`). One line,
    before any process starts.

    :param graph: any graph of ``graph/`` (its ``processes``, ``namespace``, ``params()``).
    """
    params = graph.params()
    hosted = [(base, ns.strip('/')) for proc in graph.processes
              for base, ns in proc.hosted(graph.namespace)]
    plants = {ns: effective(params, PLANT, ns) for base, ns in hosted if base == PLANT}
    defaults = {}                       # backend -> a driver's defaults
    for base, ns in hosted:
        p = effective(params, base, ns)
        label = '/%s/%s' % (ns, base) if ns else base
        why = range_refusal(base, p, label, core_keys(base, p))
        if why is None and base in DRIVERS:
            backend = p.get('backend')
            if backend not in defaults:
                defaults[backend] = driver_defaults(backend)
            p = merge(defaults[backend], p)
            plant = plants.get(ns)
            why = drive_refusal(p, (float(plant['v_min']), float(plant['v_max']))
                                if plant else None, label)
        if why:
            raise GraphError(why)
