# SPDX-License-Identifier: Apache-2.0
"""
The fiber_align ROS graph, described once (pure Python: no rclpy).

One description serves the launch file (``launch/fiber_align.launch.py``), ``bringup``,
the demo and the benchmarks: which processes run which executables and host which nodes,
which params files are read in which order, the remappings, the lifecycle-managed nodes
and how the launch arguments override parameters. The nodes themselves are the
registry's (:mod:`fiber_align.graph.registry`); which graph a set of launch arguments
starts is :func:`fiber_align.graph.arguments.describe`.

Layouts:

- multi-process (``composed=False``): one process per node, each the node's own
  executable (``simulated_actuator``, ``actuator_driver``, ...);
- composed (``composed=True``): the control nodes (plant, compensator, controller,
  driver, and the scenario runner and sequencer when the scenario needs them) in ONE
  process of the executable ``control_graph``, started as
  ``control_graph --nodes a,b,c --ros-args --params-file FILE``; each hosted node keeps
  its own name and reads its own section of the params file.

The hardware (sensorless) variant is this description with the plant swapped for the
bench: :func:`fiber_align.graph.hardware.build_hardware`.

In both layouts ``lifecycle_manager`` (brings the lifecycle nodes to active) and
``bag_recorder`` (only with ``record``) are processes of their own. The two-axis rig is
described on top of this module: :mod:`fiber_align.graph.rig`.

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

from fiber_align.config import config_dir, config_path, dump_params
from fiber_align.control.factory import CONTROLLERS
from fiber_align.graph.params import (
    check_user, COMPENSATOR, CONTROLLER, DRIVER, effective, GraphError, LIFECYCLE_MANAGER,
    merge_params, PLANT, RECORDER, SCENARIO_RUNNER, SEQUENCER, SYNC_MODES)
from fiber_align.graph.ranges import range_refusal
from fiber_align.graph.registry import (
    AREA_FILES, COMPOSED_EXECUTABLE, DEFAULT_COMPOSED, GRAPH_FILE, NODES, OPTIONAL_FILES,
    provided_topics, REMAPPINGS, SCENARIOS)
from fiber_align.plant.actuator import PARAM_KEYS, SimulatedActuator


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
    :ivar namespace: the process's own namespace (the rig's axes, ``graph/rig.py``);
        ``None``: the graph's.
    """

    name: str
    executable: str
    nodes: Tuple[str, ...]
    arguments: Tuple[str, ...] = ()
    node_name: Optional[str] = None
    ends_graph: bool = False
    namespace: Optional[str] = None

    def local_topics(self, graph_namespace=''):
        """Return the topics its nodes deliver in-process (composed), fully qualified."""
        if self.executable != COMPOSED_EXECUTABLE:
            return ()
        return tuple(t for base, ns in self.hosted(graph_namespace)
                     for t in provided_topics(base, ns))

    def hosted(self, graph_namespace=''):
        """
        Return ``(name, namespace)`` of each hosted node: its base name and full namespace.

        A node may be listed below a sub-namespace of the process's (``x/simulated_actuator``
        in the rig's one process).

        :param graph_namespace: the graph's namespace (``''``: none), for a process
            without one of its own.
        """
        ns = graph_namespace if self.namespace is None else self.namespace
        out = []
        for n in self.nodes:
            sub, _, base = n.rpartition('/')
            full = '/'.join(x for x in (ns.strip('/'), sub) if x)
            out.append((base, '/' + full))
        return out

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
        if self.node_name and self.node_name != self.executable:   # one executable, roles
            out += ['-r', '__node:=' + self.node_name]
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
    managed_nodes: Tuple[str, ...] = (DRIVER,)

    @property
    def nodes(self):
        """Return every node name of the graph, in process order."""
        return tuple(n for p in self.processes for n in p.nodes)

    def params(self):
        """Return the merged params mapping (``{key: {'ros__parameters': {...}}}``)."""
        return merge_params(self.params_files, self.overrides, self.namespace)

    def write_params(self, path):
        """Write the merged params file every process reads to ``path``; return ``path``."""
        with open(path, 'w', encoding='utf-8') as f:
            dump_params(self.params(), f)
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

    Used by ``bringup`` for its children and by the launch file. The user's ROS
    environment (``ROS_DOMAIN_ID``, ``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS``,
    ``RMW_IMPLEMENTATION``) is kept as it is: discovery follows ROS's rules
    (docs/network.md).

    Unless the user chose a Fast DDS profile, ``config/fastdds_profile.xml`` is used: a
    50 ms heartbeat, so a reliable sample dropped in a burst is resent at once instead
    of after 3 s (when its writer may have exited), larger socket buffers, and a
    participant announcement every 1 s instead of 3 s, so a newcomer (each ``ros2``
    command) finds the graph about three times sooner. The profile sets no domain,
    discovery range, peer, transport or interface; other RMWs ignore the variable.
    """
    out = dict(os.environ if env is None else env)
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


def user_files(params_file):
    """Return the user's params files (a path, a list of paths or ``''``) as absolute paths."""
    names = [params_file] if isinstance(params_file, str) else list(params_file or ())
    out = []
    for f in (n for n in names if n):
        if not os.path.isfile(f):
            raise GraphError('params_file %s does not exist' % f)
        out.append(os.path.abspath(f))
    return out


def check_record(record):
    """Return the bag directory ``record`` made absolute; raise when it exists already."""
    record = os.path.abspath(record)
    if os.path.exists(record):
        raise GraphError('record %s already exists: give a new bag directory' % record)
    return record


def graph_wide(over, sync_mode, controller):
    """Put the ``sync_mode`` and ``controller`` launch arguments (if given) into ``over``."""
    if sync_mode:
        over.setdefault('/**', {})['sync_mode'] = _choice('sync_mode', sync_mode, SYNC_MODES)
    if controller:
        over.setdefault('/**', {})['controller'] = _choice('controller', controller,
                                                           CONTROLLERS)


def add_overrides(over, overrides):
    """Return ``over`` with the user's ``{node: {name: value}}`` applied last (a copy)."""
    out = {k: dict(v) for k, v in over.items()}
    for node, params in (overrides or {}).items():
        out.setdefault('/**' if node in ('**', '/**') else node, {}).update(params)
    return out


def build(namespace='', composed=None, sync_mode='', controller='', params_file='',
          model_file='', record='', scenario='', config_directory=None, overrides=None):
    """
    Describe the graph for the given launch arguments; return a :class:`Graph`.

    Empty strings mean "as the params files say" (``record``: no recorder).

    :param namespace: namespace of every node (``''``: none).
    :param composed: layout (bool or ``'true'``/``'false'``; ``None`` or ``''``:
        :data:`DEFAULT_COMPOSED`).
    :param sync_mode: ``realtime`` | ``lockstep``: ``/**`` ``sync_mode``.
    :param controller: a name of :data:`CONTROLLERS`: ``/**`` ``controller``.
    :param params_file: a params file (or a list of them) merged after
        ``fiber_align.yaml``; checked against the shipped files
        (:func:`~fiber_align.graph.params.check_user`).
    :param model_file: PI model file: ``hysteresis_compensator.model_file`` (absolute).
    :param record: bag directory (must not exist): ``bag_recorder.output``; adds the
        recorder (composed: hosted in the control process; else a process of its own).
    :param scenario: a name of :data:`SCENARIOS`: ``scenario_runner.scenario``; other
        than ``none`` adds ``scenario_runner`` (and ``alignment_sequencer`` for align).
    :param config_directory: where the shipped files are (default: :func:`config_dir`).
    :param overrides: ``{node or '/**': {name: value}}`` applied last (``bringup -p``),
        checked against the shipped files.
    :raises GraphError: a value is not allowed or a file is missing (one clear line).
    """
    ns = check_namespace(namespace)
    composed = DEFAULT_COMPOSED if composed in (None, '') else parse_bool('composed',
                                                                          composed)
    shipped = list(area_files(config_directory))
    users = user_files(params_file)
    check_user(shipped, users, overrides)
    files = shipped + users
    over = {}
    graph_wide(over, sync_mode, controller)
    if model_file:
        if not os.path.isfile(model_file):
            raise GraphError('model_file %s does not exist' % model_file)
        over[COMPENSATOR] = {'model_file': os.path.abspath(model_file)}
    if record:
        record = check_record(record)
        over[RECORDER] = {'output': record}
        if not composed:
            # realtime per-sample topics are volatile: the clock waits for the recorder
            # (composed, it reads them in-process from before the first sample)
            over[PLANT] = {'start_after_reader': RECORDER}
    if scenario:
        # under launch the runner ends the graph when its scenario is over
        over[SCENARIO_RUNNER] = {'scenario': _choice('scenario', scenario, SCENARIOS),
                                 'exit_when_done': True, 'wait_for_recorder': bool(record)}
    over = add_overrides(over, overrides)
    merged = merge_params(files, over, ns)
    wide = effective(merged, PLANT, ns)
    sync = _choice('sync_mode', wide.get('sync_mode', 'realtime'), SYNC_MODES)
    law = _choice('controller', wide.get('controller', 'composite'), CONTROLLERS)
    scen = _choice('scenario', effective(merged, SCENARIO_RUNNER, ns).get('scenario', 'none'),
                   SCENARIOS)
    nodes = control_nodes(scen)
    if SCENARIO_RUNNER in nodes:    # the setpoints clamped to the plant's reach, as offline
        why = range_refusal(PLANT, effective(merged, PLANT, ns))    # a plant it can build
        if why:
            raise GraphError(why)
        over.setdefault(SCENARIO_RUNNER, {}).setdefault('reach_m', plant_reach_m(
            merge_params(files, over)))
    if composed:
        # one process; the recorder hosted in it reads the loop's topics from the bus,
        # no DDS between them (as the multi-axis graphs, graph/rig.py)
        hosted = nodes + ((RECORDER,) if record else ())
        procs = [Process(COMPOSED_EXECUTABLE, COMPOSED_EXECUTABLE, hosted,
                         ('--nodes', ','.join(hosted)), ends_graph=SCENARIO_RUNNER in nodes)]
    else:
        procs = [Process(n, n, (n,), node_name=n, ends_graph=n == SCENARIO_RUNNER)
                 for n in nodes]
    procs.append(Process(LIFECYCLE_MANAGER, LIFECYCLE_MANAGER, (LIFECYCLE_MANAGER,),
                         node_name=LIFECYCLE_MANAGER))
    if record and not composed:
        procs.append(Process(RECORDER, RECORDER, (RECORDER,), node_name=RECORDER))
    managed = tuple(n for n in nodes if NODES[n].lifecycle)
    over[LIFECYCLE_MANAGER] = {'node_names': list(managed)}
    return Graph(namespace=ns, composed=composed, sync_mode=sync, controller=law,
                 scenario=scen, record=record, processes=tuple(procs),
                 params_files=tuple(files), overrides=over, remappings=REMAPPINGS,
                 managed_nodes=managed)
