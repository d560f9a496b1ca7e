# SPDX-License-Identifier: Apache-2.0
"""
The two-axis rig of the fiber_align graph, described once (pure Python: no rclpy).

Built on :mod:`fiber_align.graph.description` (its :class:`~.description.Process`, params
merge and checks) and used by the launch file (``rig:=true``) and ``bringup --rig``. Under one rig
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
from typing import Callable, Dict, Tuple

from fiber_align.config import config_dir
from fiber_align.graph import description as g
from fiber_align.graph.params import (check_user, DRIVER, effective, GraphError, LIFECYCLE_MANAGER,
                                      LIVE_VIEW, merge, merge_params, OPTICS_2D as OPTICS,
                                      PLANT, RECORDER, RUN_CATALOG, SEQUENCER_2D,
                                      wildcard_first)
from fiber_align.graph.registry import NODES
from fiber_align.simulation import seeds2d

RIG_NAMESPACE = 'rig'
AXES = ('x', 'y')
#: The rig's own nodes: name -> executable (from the registry, :data:`~.registry.NODES`).
RIG_NODES = {NODES[n].node: NODES[n].executable for n in (OPTICS, SEQUENCER_2D)}
#: Each axis's nodes, in start order (the 1-D graph without a setpoint source).
AXIS_NODES = g.control_nodes('none')
#: ``control_graph --nodes`` names (registry keys) of the axis nodes that differ from the
#: node name: the rig's plant also publishes its true tip position (``rig_actuator``).
AXIS_EXECUTABLES = {PLANT: 'rig_actuator'}
#: Params files of the rig's nodes, merged after the 1-D graph's area files.
RIG_FILES = tuple(f for n in RIG_NODES for f in NODES[n].configs)


@dataclass(frozen=True)
class RigGraph(g.Graph):
    """
    The rig (a :class:`~.description.Graph` whose processes carry their own namespaces).

    Node names relative to the rig namespace: ``x/simulated_actuator``, ...,
    ``simulated_optics_2d``. ``overrides`` keys: ``/**``, a bare node name (both axes'
    nodes, or a rig node) or ``<axis>/<node>`` (one axis).
    """

    seed: int = 0
    #: the axes' namespaces below the graph's (``x``, ``y``; the station's ``in/x`` ...)
    axes: Tuple[str, ...] = AXES
    #: the nodes of the graph's own namespace besides the manager (optics, sequencer)
    own_nodes: Tuple[str, ...] = tuple(RIG_NODES)
    #: its machine's :attr:`Machine.streams`
    streams: Tuple[Tuple[str, str], ...] = ()

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
        for n in tuple(self.own_nodes) + (LIFECYCLE_MANAGER, LIVE_VIEW, RECORDER, RUN_CATALOG):
            if n in base:
                out['%s/%s' % (root, n)] = base[n]
        # a copy per section: no shared mappings, so no YAML aliases in the params file;
        # /** first, as description.py writes it (params.wildcard_first)
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


@dataclass(frozen=True)
class Machine:
    """
    A graph of several actuator axes below one namespace, as data.

    :ivar scenario: its run (``align2d``, ``station``: the offline scenario it equals).
    :ivar namespace: its namespace when none is given (and its composed process's name).
    :ivar axes: the axes' namespaces below it (``x``, ``y``; ``in/x`` ...).
    :ivar own: ``{node: executable}`` of its nodes in its own namespace (optics, sequencer).
    :ivar plant_seeds: ``seed -> (noise seed of each axis's plant)`` for the run seed.
    :ivar seeded: ``seed -> {node: {name: value}}``: what else the run seed sets.
    :ivar recorded: the topics ``record`` records (relative; empty: no ``record``).
    :ivar streams: ``((trace column, topic), ...)``: the per-sample streams of the run
        (relative topics), named as the offline bench's trace columns a lockstep run is
        compared with (:func:`fiber_align.analysis.run_summary.compare_offline`).
    """

    scenario: str
    namespace: str
    axes: Tuple[str, ...]
    own: Dict[str, str]
    plant_seeds: Callable
    seeded: Callable
    recorded: Tuple[str, ...] = ()
    streams: Tuple[Tuple[str, str], ...] = ()


def build_axes(m, namespace='', composed=None, sync_mode='', controller='', params_file='',
               seed=0, record='', config_directory=None, overrides=None):
    """
    Describe the multi-axis graph ``m`` for the given launch arguments; return a :class:`RigGraph`.

    :param m: the :class:`Machine` (:data:`RIG`, :data:`fiber_align.graph.station.STATION`).
    :param namespace: its namespace (``''``: ``m.namespace``).
    :param composed: layout (bool or ``'true'``/``'false'``; ``None``/``''``: default).
    :param sync_mode: ``realtime`` | ``lockstep`` (``''``: as the params files say).
    :param controller: control law of every axis (``''``: as the params files say).
    :param params_file: a params file merged after ``fiber_align.yaml`` (bare node
        sections apply to every axis, ``<axis>/<node>`` to one).
    :param seed: the run seed ``S`` (seeds, target or facets as offline).
    :param record: bag directory (must not exist; machines with :attr:`Machine.recorded`).
    :param overrides: further ``{node: {name: value}}`` (bringup's options), applied last.
    :raises GraphError: a value is not allowed or a file is missing.
    """
    ns = g.check_namespace(namespace or m.namespace)
    composed = g.DEFAULT_COMPOSED if composed in (None, '') else g.parse_bool('composed',
                                                                              composed)
    files = multi_axis_files(config_directory, m.own, params_file, overrides)
    seed = check_seed(seed)
    over = {'/**': {}}
    g.graph_wide(over, sync_mode, controller)
    over[PLANT] = {'optical_power_every': 0, 'tip_position_every': 1}
    for i, (a, s) in enumerate(zip(m.axes, m.plant_seeds(seed))):
        over['%s/%s' % (a, PLANT)] = {'seed': s, 'publish_clock': i == 0}
    over.update(m.seeded(seed))
    managed = tuple('%s/%s' % (a, DRIVER) for a in m.axes)
    over[LIFECYCLE_MANAGER] = {'node_names': list(managed)}
    if record:
        record = g.check_record(record)
        over[RECORDER] = {'output': record, 'topics': list(m.recorded)}
        if not composed:
            # realtime per-sample topics are volatile: the clock waits for the recorder
            # (composed, it reads them in-process from before the first sample)
            over[PLANT]['start_after_reader'] = '/%s/%s' % (ns, RECORDER) if ns else RECORDER
    over = g.add_overrides(over, overrides)
    sync, law = in_effect(files, over)
    return RigGraph(namespace=ns, composed=composed, sync_mode=sync, controller=law,
                    scenario=m.scenario, record=record or '',
                    processes=rig_processes(ns, composed, m.axes, m.own, m.namespace,
                                            bool(record)),
                    params_files=tuple(files), overrides=over, remappings=g.REMAPPINGS,
                    managed_nodes=managed, seed=seed, axes=m.axes, own_nodes=tuple(m.own),
                    streams=m.streams)


def multi_axis_files(config_directory, own, params_file, overrides):
    """Return the params files of a multi-axis graph: area files, its nodes', the user's."""
    d = config_dir() if config_directory is None else config_directory
    files = list(g.area_files(d)) + [os.path.join(str(d), f) for n in own
                                     for f in NODES[n].configs]
    users = g.user_files(params_file)
    check_user(files, users, overrides)
    return list(dict.fromkeys(files + users))


def in_effect(files, over):
    """Return ``(sync_mode, controller)`` in effect after every file and override."""
    plant = effective(merge_params(files, over), PLANT)
    return (g._choice('sync_mode', plant.get('sync_mode', 'realtime'), g.SYNC_MODES),
            g._choice('controller', plant.get('controller', 'composite'), g.CONTROLLERS))


def _rig_seeded(seed):
    seeds, target = seeds2d.run_seeds(seed), seeds2d.random_target(seed)
    return {OPTICS: {'seed': seeds['detector'], 'target.position_x_m': target[0],
                     'target.position_y_m': target[1]}}


#: The rig's per-sample streams: the setpoints as the loop accepted them (``reference``):
#: a command topic keeps one reader, the loop's (:data:`~.registry.COMMANDS`).
RIG_STREAMS = (('mx', 'x/displacement'), ('my', 'y/displacement'), ('p', 'optical_power'),
               ('rx', 'x/reference'), ('ry', 'y/reference'))
#: The two-axis rig: plant seeds ``2 S``, ``2 S + 1``, detector seed ``S + 1000``, the
#: target ``random_target(S)`` (:mod:`fiber_align.simulation.seeds2d`).
RIG = Machine('align2d', RIG_NAMESPACE, AXES, RIG_NODES,
              lambda seed: (seeds2d.run_seeds(seed)['plant_x'],
                            seeds2d.run_seeds(seed)['plant_y']), _rig_seeded,
              streams=RIG_STREAMS)


def build_rig(namespace=RIG_NAMESPACE, composed=None, sync_mode='', controller='',
              params_file='', seed=0, config_directory=None, overrides=None):
    """Describe the rig for the given launch arguments (:func:`build_axes` of :data:`RIG`)."""
    return build_axes(RIG, namespace, composed, sync_mode, controller, params_file, seed,
                      config_directory=config_directory, overrides=overrides)
