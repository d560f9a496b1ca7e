# SPDX-License-Identifier: Apache-2.0
"""
The two-axis rig of the fiber_align graph, described once (pure Python: no rclpy).

Built on :mod:`fiber_align.graph.description` (its :class:`~graph.Process`, params merge and
checks) and used by the launch file (``rig:=true``) and ``bringup --rig``. Under one rig
namespace (``rig`` unless told):

- ``/rig/x/...`` and ``/rig/y/...``: two actuator graphs, each the control nodes of the
  1-D graph (``simulated_actuator``, ``hysteresis_compensator``, ``fuzzy_pid_controller``,
  ``actuator_driver``) with its own plant, sensor-noise seed and params sections
  (``/rig/x/simulated_actuator``, ...); the plant (``control_graph`` name
  ``rig_actuator``) is the 1-D plant's executable publishing its true tip position too;
- ``/rig/simulated_optics_2d`` (executable ``simulated_optics``): reads both true tip
  positions (``x/tip_position``, ``y/tip_position``), publishes ``optical_power`` (W);
- ``/rig/alignment_sequencer_2d`` (executable ``alignment_sequencer``): the 2-D
  sequencer, ``x/setpoint`` and ``y/setpoint``, services ``align``, ``release``,
  ``switch``;
- ``/rig/lifecycle_manager``: activates ``x/actuator_driver`` and ``y/actuator_driver``.

Layouts as in the 1-D graph: composed (default): one ``control_graph`` process hosting
both axes, the optics and the sequencer (``--nodes x/rig_actuator,...,simulated_optics_2d,
alignment_sequencer_2d``: every per-sample message between them is an in-process call);
multi-process: one process per node.

The run's description is the offline one (:mod:`fiber_align.simulation.
alignment2d_scenarios`): plant seeds ``2 S`` (x) and ``2 S + 1`` (y), detector seed
``S + 1000`` and the target ``random_target(S)`` for the run seed ``S``; the control period
of the optics and the sequencer is the plants' ``1 / rate_hz``. The lockstep sample clock:
each plant advances when its drive for sample k arrives, the drives need the sequencer's
setpoints of sample k, which need both displacements and the power of sample k, so the
two plants and the optics advance in step; the x plant publishes ``/clock``.
"""

import copy
from dataclasses import dataclass
import os
from typing import Tuple

from fiber_align.config import config_dir
from fiber_align.graph import description as g
from fiber_align.graph.params import (check_user, DRIVER, effective, GraphError, LIFECYCLE_MANAGER,
                                      LIVE_VIEW, merge, merge_params, PLANT, RECORDER,
                                      wildcard_first)
from fiber_align.simulation import seeds2d

RIG_NAMESPACE = 'rig'
AXES = ('x', 'y')
OPTICS = 'simulated_optics_2d'
SEQUENCER_2D = 'alignment_sequencer_2d'
#: The rig's own nodes: name -> executable (from the registry, :data:`~graph.NODES`).
RIG_NODES = {g.NODES[n].node: g.NODES[n].executable for n in (OPTICS, SEQUENCER_2D)}
#: Each axis's nodes, in start order (the 1-D graph without a setpoint source).
AXIS_NODES = g.control_nodes('none')
#: ``control_graph --nodes`` names (registry keys) of the axis nodes that differ from the
#: node name: the rig's plant also publishes its true tip position (``rig_actuator``).
AXIS_EXECUTABLES = {PLANT: 'rig_actuator'}
#: Params files of the rig's nodes, merged after the 1-D graph's area files.
RIG_FILES = tuple(f for n in RIG_NODES for f in g.NODES[n].configs)
MANAGED = tuple('%s/%s' % (a, DRIVER) for a in AXES)


@dataclass(frozen=True)
class RigGraph(g.Graph):
    """
    The rig (a :class:`~graph.Graph` whose processes carry their own namespaces).

    Node names relative to the rig namespace: ``x/simulated_actuator``, ...,
    ``simulated_optics_2d``. ``overrides`` keys: ``/**``, a bare node name (both axes'
    nodes, or a rig node) or ``<axis>/<node>`` (one axis).
    """

    seed: int = 0
    #: the axes' namespaces below the graph's (``x``, ``y``; the station's ``in/x`` ...)
    axes: Tuple[str, ...] = AXES
    #: the nodes of the graph's own namespace besides the manager (optics, sequencer)
    own_nodes: Tuple[str, ...] = tuple(RIG_NODES)

    @property
    def nodes(self):
        """Return every node name relative to the rig namespace, in process order."""
        root = '/' + self.namespace.strip('/') if self.namespace else ''
        return tuple((ns[len(root):].strip('/') + '/' + n).lstrip('/')
                     for p in self.processes for n, ns in p.hosted(self.namespace))

    def params(self):
        """Return the merged params mapping, node sections keyed ``/<ns>[/<axis>]/<node>``."""
        base = merge_params(self.params_files, self.overrides)
        root = '/' + self.namespace if self.namespace else ''
        out = {'/**': base.get('/**', {'ros__parameters': {}})}
        for a in self.axes:
            for n in AXIS_NODES:
                sec = merge(base.get(n, {}), base.get('%s/%s' % (a, n), {}))
                if sec:
                    out['%s/%s/%s' % (root, a, n)] = sec
        for n in tuple(self.own_nodes) + (LIFECYCLE_MANAGER, LIVE_VIEW, RECORDER):
            if n in base:
                out['%s/%s' % (root, n)] = base[n]
        # a copy per section: no shared mappings, so no YAML aliases in the params file;
        # /** first, as graph.py writes it (graph_params.wildcard_first)
        return wildcard_first({k: copy.deepcopy(v) for k, v in out.items()})

    def node_params(self, node):
        """Return the effective parameters of ``node`` (relative: ``x/simulated_actuator``)."""
        return effective(self.params(), node, self.namespace)


def _axis_ns(ns, axis):
    return '%s/%s' % (ns, axis) if ns else axis


def rig_processes(ns, composed, axes=AXES, own=None, label='rig', record=False):
    """
    Return the processes (each with its namespace), the manager (and recorder) last.

    :param axes: the axes' namespaces below ``ns``.
    :param own: ``{node: executable}`` of the nodes in ``ns`` itself (default the rig's).
    :param label: the composed process's name.
    :param record: add the recorder (in ``ns``): composed, hosted in the one process (it
        reads the axes' topics from the bus, no DDS between them); else a process.
    """
    own = RIG_NODES if own is None else own
    if composed:
        # one process: every axis and the optics exchange every sample in-process
        here = tuple(own) + ((RECORDER,) if record else ())
        nodes = tuple('%s/%s' % (a, n) for a in axes for n in AXIS_NODES) + here
        hosted = ['%s/%s' % (a, AXIS_EXECUTABLES.get(n, n)) for a in axes
                  for n in AXIS_NODES] + list(here)
        procs = [g.Process(label, g.COMPOSED_EXECUTABLE, nodes, ('--nodes', ','.join(hosted)),
                           namespace=ns)]
    else:
        procs = [g.Process('%s/%s' % (a, n), g.NODES[AXIS_EXECUTABLES.get(n, n)].executable,
                           (n,), node_name=n,
                           namespace=_axis_ns(ns, a)) for a in axes for n in AXIS_NODES]
        procs += [g.Process(n, exe, (n,), node_name=n, namespace=ns)
                  for n, exe in own.items()]
    procs.append(g.Process(LIFECYCLE_MANAGER, LIFECYCLE_MANAGER, (LIFECYCLE_MANAGER,),
                           node_name=LIFECYCLE_MANAGER, namespace=ns))
    if record and not composed:
        procs.append(g.Process(RECORDER, RECORDER, (RECORDER,), node_name=RECORDER,
                               namespace=ns))
    return tuple(procs)


def check_seed(seed):
    """Return the run seed as an int >= 0, or raise :class:`GraphError`."""
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise GraphError('seed %r is not allowed: an integer >= 0' % (seed,)) from None
    if seed < 0:
        raise GraphError('seed %r is not allowed: an integer >= 0' % seed)
    return seed


def multi_axis_start(namespace, composed, config_directory, own, params_file, overrides,
                     seed, sync_mode, controller):
    """
    Return what every multi-axis graph checks first: ``(ns, composed, files, seed, over)``.

    The namespace and layout checked, the params files (:func:`multi_axis_files`), the
    run seed (:func:`check_seed`) and the overrides started with the graph-wide
    ``sync_mode`` and ``controller`` (:func:`~fiber_align.graph.description.graph_wide`).
    """
    ns = g.check_namespace(namespace)
    composed = g.DEFAULT_COMPOSED if composed in (None, '') else g.parse_bool('composed',
                                                                              composed)
    files = multi_axis_files(config_directory, own, params_file, overrides)
    over = {'/**': {}}
    g.graph_wide(over, sync_mode, controller)
    return ns, composed, files, check_seed(seed), over


def multi_axis_files(config_directory, own, params_file, overrides):
    """Return the params files of a multi-axis graph: area files, its nodes', the user's."""
    d = config_dir() if config_directory is None else config_directory
    files = list(g.area_files(d)) + [os.path.join(str(d), f) for n in own
                                     for f in g.NODES[n].configs]
    users = g.user_files(params_file)
    check_user(files, users, overrides)
    return list(dict.fromkeys(files + users))


def in_effect(files, over):
    """Return ``(sync_mode, controller)`` in effect after every file and override."""
    plant = effective(merge_params(files, over), PLANT)
    return (g._choice('sync_mode', plant.get('sync_mode', 'realtime'), g.SYNC_MODES),
            g._choice('controller', plant.get('controller', 'composite'), g.CONTROLLERS))


def build_rig(namespace=RIG_NAMESPACE, composed=None, sync_mode='', controller='',
              params_file='', seed=0, config_directory=None, overrides=None):
    """
    Describe the rig for the given launch arguments; return a :class:`RigGraph`.

    :param namespace: the rig namespace (``rig``).
    :param composed: layout (bool or ``'true'``/``'false'``; ``None``/``''``: default).
    :param sync_mode: ``realtime`` | ``lockstep`` (``''``: as the params files say).
    :param controller: control law of both axes (``''``: as the params files say).
    :param params_file: a params file merged after ``fiber_align.yaml`` (bare node
        sections apply to both axes, ``x/<node>`` to one).
    :param seed: the run seed ``S`` (seeds and target as offline, module docstring).
    :param overrides: further ``{node: {name: value}}`` (bringup's options), applied last.
    :raises GraphError: a value is not allowed or a file is missing.
    """
    ns, composed, files, seed, over = multi_axis_start(
        namespace, composed, config_directory, RIG_NODES, params_file, overrides, seed,
        sync_mode, controller)
    seeds = seeds2d.run_seeds(seed)
    target = seeds2d.random_target(seed)
    over[PLANT] = {'optical_power_every': 0, 'tip_position_every': 1}
    over['x/' + PLANT] = {'seed': seeds['plant_x'], 'publish_clock': True}
    over['y/' + PLANT] = {'seed': seeds['plant_y'], 'publish_clock': False}
    over[OPTICS] = {'seed': seeds['detector'], 'target.position_x_m': target[0],
                    'target.position_y_m': target[1]}
    over[LIFECYCLE_MANAGER] = {'managed_nodes': list(MANAGED)}
    over = g.add_overrides(over, overrides)
    sync, law = in_effect(files, over)
    return RigGraph(namespace=ns, composed=composed, sync_mode=sync, controller=law,
                    scenario='align2d', record='', processes=rig_processes(ns, composed),
                    params_files=tuple(files), overrides=over, remappings=g.REMAPPINGS,
                    managed_nodes=MANAGED, seed=seed)
