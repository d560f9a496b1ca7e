# SPDX-License-Identifier: Apache-2.0
"""
The fiber_align ROS graph, described once (pure Python: no rclpy).

One description serves the launch file (``launch/fiber_align.launch.py``), ``bringup``,
the demo and the benchmarks: which processes run which executables and host which nodes,
which params files are read in which order, the remappings, the lifecycle-managed nodes
and how the launch arguments override parameters.

Layouts:

- multi-process (``composed=False``): one process per node, each the node's own
  executable (``simulated_actuator``, ``actuator_driver``, ...);
- composed (``composed=True``): the control nodes (plant, compensator, controller,
  driver, and the scenario runner and sequencer when the scenario needs them) in ONE
  process of the executable ``control_graph``, started as
  ``control_graph --nodes a,b,c --ros-args --params-file FILE``; each hosted node keeps
  its own name and reads its own section of the params file.

The hardware (sensorless) variant is this description with the plant swapped for the
bench: :func:`fiber_align.nodes.graph_hardware.build_hardware`.

In both layouts ``lifecycle_manager`` (brings the lifecycle nodes to active) and
``bag_recorder`` (only with ``record``) are processes of their own. The two-axis rig is
described on top of this module: ``graph_rig.py``.

Parameters: every process gets ONE params file (:meth:`Graph.write_params`), the merge of
the per-area files (:data:`AREA_FILES`), ``fiber_align.yaml``, the user's ``params_file``
and the launch-argument overrides, later ones winning, with numeric lists made float
lists (ROS arrays are homogeneous) and node sections keyed ``/<namespace>/<node>``
when there is a namespace (a bare ``node`` key would only match ``/node``).

Example::

    g = build(namespace='left', sync_mode='lockstep', scenario='sine')
    g.write_params('/tmp/params.yaml')
    for p in g.processes:
        argv = p.command('/tmp/params.yaml', g.namespace, g.remappings, sys.executable)
"""

from dataclasses import dataclass, field
import os
import re
from typing import Dict, Optional, Tuple

from fiber_align.config import config_dir, config_path
from fiber_align.plant.actuator import PARAM_KEYS, SimulatedActuator
# The node names and the params-merge law live in graph_params; re-exported here.
from fiber_align.nodes.graph_params import (  # noqa: F401
    PLANT,
    COMPENSATOR,
    CONTROLLER,
    DRIVER,
    SCENARIO_RUNNER,
    SEQUENCER,
    RECORDER,
    LIFECYCLE_MANAGER,
    LIFECYCLE_NODES,
    LOOP_NODES,
    SHAPING_KEYS,
    SHARED,
    GraphError,
    normalize,
    merge,
    nest,
    _section_key,
    lift_shared,
    wildcard_first,
    merge_params,
    effective)

PACKAGE = 'fiber_align'
#: Layout when the launch argument ``composed`` (or bringup's option) is not given.
DEFAULT_COMPOSED = True
#: Executable that hosts several nodes in one process (composed layout).
COMPOSED_EXECUTABLE = 'control_graph'
#: Per-area params files, in the order they are merged (names in ``config/``).
AREA_FILES = ('plant.yaml', 'optics.yaml', 'controller.yaml', 'compensator.yaml',
              'models/compensator_model.yaml', 'driver.yaml', 'sequencer.yaml',
              'recorder.yaml', 'scenario.yaml', 'lifecycle_manager.yaml')
#: Area files a checkout may not have yet (skipped when missing).
OPTIONAL_FILES = ()
#: Graph-wide params file, merged after the per-area files.
GRAPH_FILE = 'fiber_align.yaml'

SYNC_MODES = ('realtime', 'lockstep')
#: Control laws, as in ``fiber-align simulate --controller``.
CONTROLLERS = ('composite', 'composite-pid', 'fuzzy', 'pid', 'feedforward', 'open-loop')
SCENARIOS = ('none', 'step', 'sine', 'triangle', 'staircase', 'hysteresis-experiment',
             'align')

#: Remappings applied to every process (``from``, ``to``); the nodes use the graph's
#: relative names as they are, so there are none today.
REMAPPINGS = ()


@dataclass(frozen=True)
class Process:
    """
    One OS process of the graph.

    :ivar name: label of the process (its node's name, or ``control_graph``).
    :ivar executable: executable in ``lib/fiber_align`` (also ``fiber_align.nodes.<name>``).
    :ivar nodes: names of the nodes it hosts (relative; each reads its own params section).
    :ivar arguments: arguments before ``--ros-args`` (``--nodes a,b`` when composed).
    :ivar node_name: the node name to pass as ``name`` to launch_ros (single-node
        processes only; ``None`` for a process hosting several nodes).
    :ivar ends_graph: the graph stops when this process exits (it hosts
        ``scenario_runner``, which exits when its scenario is over).
    :ivar namespace: the process's own namespace (the rig's axes, ``graph_rig.py``);
        ``None``: the graph's.
    """

    name: str
    executable: str
    nodes: Tuple[str, ...]
    arguments: Tuple[str, ...] = ()
    node_name: Optional[str] = None
    ends_graph: bool = False
    namespace: Optional[str] = None

    @property
    def module(self):
        """Return the Python module of the executable (``python -m`` form)."""
        return 'fiber_align.nodes.' + self.executable

    def ros_args(self, params_file, namespace='', remappings=()):
        """
        Return the ``--ros-args`` part of the command line (list of str).

        :param params_file: the graph's params file (:meth:`Graph.write_params`).
        :param namespace: the graph's namespace (``''``: none).
        :param remappings: (from, to) pairs.
        """
        out = ['--ros-args', '--params-file', str(params_file)]
        namespace = namespace if self.namespace is None else self.namespace
        if namespace:
            out += ['-r', '__ns:=/' + namespace]
        for a, b in remappings:
            out += ['-r', '%s:=%s' % (a, b)]
        return out

    def argv(self, params_file, namespace='', remappings=()):
        """Return the arguments after the executable (list of str)."""
        return list(self.arguments) + self.ros_args(params_file, namespace, remappings)

    def command(self, params_file, namespace='', remappings=(), python=None):
        """
        Return the full command line (list of str).

        :param python: an interpreter: run ``python -m fiber_align.nodes.<executable>``
            (the pip route, no ``lib/fiber_align`` needed); ``None``: the executable name.
        """
        head = [python, '-m', self.module] if python else [self.executable]
        return head + self.argv(params_file, namespace, remappings)


@dataclass(frozen=True)
class Graph:
    """
    The graph to start: processes, params and settings in effect.

    :ivar namespace: namespace of every node, without leading or trailing ``/``.
    :ivar composed: the layout (see the module docstring).
    :ivar sync_mode: ``realtime`` or ``lockstep`` (in effect after every override).
    :ivar controller: control law in effect.
    :ivar scenario: scenario in effect (``none``: the graph waits for setpoints).
    :ivar record: bag directory (absolute) or ``''`` (no recorder).
    :ivar processes: the processes, control graph first, the manager and recorder last.
    :ivar params_files: the files merged, in order (absolute paths).
    :ivar overrides: node (or ``/**``) -> {parameter: value}, applied after the files.
    :ivar remappings: (from, to) pairs for every process.
    :ivar managed_nodes: lifecycle nodes, in the order the manager activates them.
    """

    namespace: str
    composed: bool
    sync_mode: str
    controller: str
    scenario: str
    record: str
    processes: Tuple[Process, ...]
    params_files: Tuple[str, ...]
    overrides: Dict[str, Dict[str, object]] = field(default_factory=dict)
    remappings: Tuple[Tuple[str, str], ...] = REMAPPINGS
    managed_nodes: Tuple[str, ...] = LIFECYCLE_NODES

    @property
    def nodes(self):
        """Return every node name of the graph, in process order."""
        return tuple(n for p in self.processes for n in p.nodes)

    def params(self):
        """Return the merged params mapping (``{key: {'ros__parameters': {...}}}``)."""
        return merge_params(self.params_files, self.overrides, self.namespace)

    def write_params(self, path):
        """Write the merged params file every process reads to ``path``; return ``path``."""
        import yaml
        with open(path, 'w', encoding='utf-8') as f:
            yaml.safe_dump(self.params(), f, sort_keys=False)
        return path

    def node_params(self, node):
        """Return the effective parameters of ``node`` (``/**`` then its section)."""
        return effective(self.params(), node, self.namespace)


def control_nodes(scenario):
    """Return the names of the control nodes the scenario needs, in start order."""
    if scenario == 'hysteresis-experiment':   # open loop: the runner drives the driver
        return (PLANT, SCENARIO_RUNNER, DRIVER)
    nodes = (PLANT, COMPENSATOR, CONTROLLER, DRIVER)
    if scenario == 'none':
        return nodes
    if scenario == 'align':         # the sequencer is the setpoint source
        return nodes + (SEQUENCER,)
    return nodes + (SCENARIO_RUNNER,)


def plant_reach_m(params):
    """
    Return the simulated plant's largest reachable displacement (m).

    :param params: the merged params mapping (:meth:`Graph.params`-like, keyed by node).
    The scenario runner clamps its setpoints to it, as the offline simulation does, so the
    launch file, ``bringup`` and ``fiber-align simulate`` run the same setpoints.
    """
    p = effective(params, PLANT)
    return SimulatedActuator.from_params({k: p[k] for k in PARAM_KEYS if k in p}) \
        .reachable_m()


def dds_environment(env=None):
    """
    Return the environment of the graph's processes (a copy of ``env`` or os.environ).

    Used by ``bringup`` for its children and by the launch file.

    Unless the user chose a Fast DDS profile, ``config/fastdds_profile.xml`` is used: a
    50 ms heartbeat, so a reliable sample dropped in a burst is resent at once instead
    of after 3 s (when its writer may have exited), and larger socket buffers.
    """
    out = dict(os.environ if env is None else env)
    out.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if 'FASTRTPS_DEFAULT_PROFILES_FILE' not in out:
        out['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(config_path('fastdds_profile.xml'))
    return out


def area_files(directory=None):
    """Return the absolute paths of the area files and ``fiber_align.yaml``, in order."""
    d = config_dir() if directory is None else directory
    out = []
    for name in AREA_FILES + (GRAPH_FILE,):
        p = os.path.join(str(d), name)
        if not os.path.isfile(p):
            if name in OPTIONAL_FILES:
                continue
            raise GraphError('config file %s is missing' % p)
        out.append(p)
    return tuple(out)


_NAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*$')


def check_namespace(namespace):
    """Return ``namespace`` without outer ``/``; raise :class:`GraphError` if invalid."""
    ns = (namespace or '').strip()
    inner = ns.strip('/')
    if inner and (any(not _NAME.match(t) for t in inner.split('/')) or '//' in ns):
        raise GraphError('namespace %r is not a valid ROS namespace: tokens of letters, '
                         'digits and _ separated by /, not starting with a digit' % namespace)
    return inner


def _choice(what, value, allowed):
    if value not in allowed:
        raise GraphError('%s %r is not allowed: one of %s' % (what, value, ', '.join(allowed)))
    return value


def parse_bool(what, value):
    """Return ``value`` (bool or a launch-argument string) as a bool, or raise."""
    if isinstance(value, bool):
        return value
    s = str(value).strip().lower()
    if s in ('true', '1', 'yes', 'on'):
        return True
    if s in ('false', '0', 'no', 'off'):
        return False
    raise GraphError('%s %r is not allowed: true or false' % (what, value))


def build(namespace='', composed=None, sync_mode='', controller='', params_file='',
          model_file='', record='', scenario='', config_directory=None):
    """
    Describe the graph for the given launch arguments; return a :class:`Graph`.

    Empty strings mean "as the params files say" (``record``: no recorder).

    :param namespace: namespace of every node (``''``: none).
    :param composed: layout (bool or ``'true'``/``'false'``; ``None`` or ``''``:
        :data:`DEFAULT_COMPOSED`).
    :param sync_mode: ``realtime`` | ``lockstep``: ``/**`` ``sync_mode``.
    :param controller: a name of :data:`CONTROLLERS`: ``/**`` ``controller``.
    :param params_file: a params file merged after ``fiber_align.yaml``.
    :param model_file: PI model file: ``hysteresis_compensator.model_file`` (absolute).
    :param record: bag directory (must not exist): ``bag_recorder.output``; adds the
        recorder process.
    :param scenario: a name of :data:`SCENARIOS`: ``scenario_runner.scenario``; other
        than ``none`` adds ``scenario_runner`` (and ``alignment_sequencer`` for align).
    :param config_directory: where the shipped files are (default: :func:`config_dir`).
    :raises GraphError: a value is not allowed or a file is missing (one clear line).
    """
    ns = check_namespace(namespace)
    composed = DEFAULT_COMPOSED if composed in (None, '') else parse_bool('composed',
                                                                          composed)
    files = list(area_files(config_directory))
    if params_file:
        if not os.path.isfile(params_file):
            raise GraphError('params_file %s does not exist' % params_file)
        files.append(os.path.abspath(params_file))
    over = {}
    if sync_mode:
        over.setdefault('/**', {})['sync_mode'] = _choice('sync_mode', sync_mode, SYNC_MODES)
    if controller:
        over.setdefault('/**', {})['controller'] = _choice('controller', controller,
                                                           CONTROLLERS)
    if model_file:
        if not os.path.isfile(model_file):
            raise GraphError('model_file %s does not exist' % model_file)
        over[COMPENSATOR] = {'model_file': os.path.abspath(model_file)}
    if record:
        record = os.path.abspath(record)
        if os.path.exists(record):
            raise GraphError('record %s already exists: give a new bag directory' % record)
        over[RECORDER] = {'output': record}
    if scenario:
        # under launch the runner ends the graph when its scenario is over
        over[SCENARIO_RUNNER] = {'scenario': _choice('scenario', scenario, SCENARIOS),
                                 'exit_when_done': True, 'wait_for_recorder': bool(record)}
    merged = merge_params(files, over, ns)
    if SCENARIO_RUNNER in over:
        over[SCENARIO_RUNNER]['reach_m'] = plant_reach_m(merge_params(files, over))
    graph_wide = effective(merged, PLANT, ns)
    sync = _choice('sync_mode', graph_wide.get('sync_mode', 'realtime'), SYNC_MODES)
    law = _choice('controller', graph_wide.get('controller', 'composite'), CONTROLLERS)
    scen = _choice('scenario', effective(merged, SCENARIO_RUNNER, ns).get('scenario', 'none'),
                   SCENARIOS)
    nodes = control_nodes(scen)
    if composed:
        procs = [Process(COMPOSED_EXECUTABLE, COMPOSED_EXECUTABLE, nodes,
                         ('--nodes', ','.join(nodes)), ends_graph=SCENARIO_RUNNER in nodes)]
    else:
        procs = [Process(n, n, (n,), node_name=n, ends_graph=n == SCENARIO_RUNNER)
                 for n in nodes]
    procs.append(Process(LIFECYCLE_MANAGER, LIFECYCLE_MANAGER, (LIFECYCLE_MANAGER,),
                         node_name=LIFECYCLE_MANAGER))
    if record:
        procs.append(Process(RECORDER, RECORDER, (RECORDER,), node_name=RECORDER))
    managed = tuple(n for n in nodes if n in LIFECYCLE_NODES)
    over[LIFECYCLE_MANAGER] = {'managed_nodes': list(managed)}
    return Graph(namespace=ns, composed=composed, sync_mode=sync, controller=law,
                 scenario=scen, record=record, processes=tuple(procs),
                 params_files=tuple(files), overrides=over, remappings=REMAPPINGS,
                 managed_nodes=managed)
