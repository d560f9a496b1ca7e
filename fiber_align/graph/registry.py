# SPDX-License-Identifier: Apache-2.0
"""
The node registry of the fiber_align graphs: every node, once, as data (pure: no rclpy).

:data:`NODES` (executable, class, params files, lifecycle, topics) is the one list of
nodes: ``control_graph`` hosts from it (:data:`HOSTABLE`), :data:`AREA_FILES`, the live
view's topics and ``bringup``'s endpoint checks (:func:`expected_endpoints`) derive from
it. A new node touches its module, its config file, ``setup.py`` and this registry; the
processes that run it are described in :mod:`fiber_align.graph.description`. The
enumerations the launch arguments take are each defined once where their concept lives:
:data:`fiber_align.graph.params.SYNC_MODES`, :data:`fiber_align.control.factory.CONTROLLERS`,
:data:`fiber_align.simulation.scenarios.GRAPH` (the 1-D graph's scenarios).
"""

from dataclasses import dataclass
from typing import Tuple

from fiber_align.graph.params import (
    COMPENSATOR, CONTROLLER, DRIVER, LIFECYCLE_MANAGER, LIVE_VIEW, PLANT, RECORDER,
    RUN_CATALOG, SCENARIO_RUNNER, SEQUENCER)
from fiber_align.simulation.scenarios import GRAPH as GRAPH_SCENARIOS

PACKAGE = 'fiber_align'
#: Layout when the launch argument ``composed`` (or bringup's option) is not given.
DEFAULT_COMPOSED = True
#: Executable that hosts several nodes in one process (composed layout).
COMPOSED_EXECUTABLE = 'control_graph'


@dataclass(frozen=True)
class NodeSpec:
    """
    One node the graph can run: what a new node adds to the description.

    :ivar node: its ROS node name.
    :ivar executable: its executable in ``lib/fiber_align`` (module
        ``fiber_align.nodes.<executable>``).
    :ivar node_class: its class in that module, when ``control_graph`` can host it
        (``''``: a process of its own only).
    :ivar configs: its params files in ``config/``, merged in this order.
    :ivar lifecycle: a lifecycle (managed) node, brought to active by ``lifecycle_manager``.
    :ivar publishes: topics it publishes (relative names; ``/clock`` aside).
    :ivar subscribes: topics it subscribes to (relative names).
    :ivar area: its configs are area files of the 1-D graph (:data:`AREA_FILES`).
    """

    node: str
    executable: str
    node_class: str = ''
    configs: Tuple[str, ...] = ()
    lifecycle: bool = False
    publishes: Tuple[str, ...] = ()
    subscribes: Tuple[str, ...] = ()
    area: bool = True


#: The coupled station's axes (namespaces below the station's: input x-y, output x-y).
STATION_AXES = ('in/x', 'in/y', 'out/x', 'out/y')
#: The fiber array's actuators (namespaces below the array's: x, and y under each end).
ARRAY_AXES = ('x', 'y_left', 'y_right')
#: The array's measured channels (1 and N): the topic of each one's reading (W).
ARRAY_POWERS = ('optical_power', 'optical_power_n')
#: Every node of the graphs, keyed by its ``control_graph --nodes`` name (its executable).
#: Hostable nodes are built, and so served in-process, in this order: the plant, then the
#: setpoint sources (their answer to a sample reaches the compensator and the controller
#: within the same control period), the compensator, the controller, the driver.
NODES = {
    PLANT: NodeSpec(PLANT, PLANT, 'SimulatedActuatorNode', ('plant.yaml', 'optics.yaml'),
                    publishes=('displacement', 'optical_power'), subscribes=('drive_voltage',)),
    # the rig's plant (graph/rig.py): the 1-D plant node publishing its tip position too
    'rig_actuator': NodeSpec(PLANT, PLANT, 'SimulatedActuatorNode', area=False,
                             publishes=('displacement', 'optical_power', 'tip_position'),
                             subscribes=('drive_voltage',)),
    SCENARIO_RUNNER: NodeSpec(SCENARIO_RUNNER, SCENARIO_RUNNER, 'ScenarioRunnerNode',
                              ('scenario.yaml',), publishes=('setpoint',),
                              subscribes=('displacement',)),
    SEQUENCER: NodeSpec(SEQUENCER, SEQUENCER, 'AlignmentSequencerNode', ('sequencer.yaml',),
                        publishes=('setpoint', 'alignment_state'),
                        subscribes=('displacement', 'optical_power')),
    'simulated_optics_2d': NodeSpec('simulated_optics_2d', 'simulated_optics',
                                    'SimulatedOpticsNode',
                                    ('optics2d.yaml',), area=False,
                                    publishes=('optical_power',),
                                    subscribes=('x/tip_position', 'y/tip_position')),
    'alignment_sequencer_2d': NodeSpec('alignment_sequencer_2d', 'alignment_sequencer',
                                       'RigSequencerNode', ('sequencer2d.yaml',),
                                       area=False, publishes=('x/setpoint', 'y/setpoint'),
                                       subscribes=('optical_power',)),
    # the coupled station (graph/station.py): four axes in/x .. out/y
    'simulated_station_optics': NodeSpec(
        'simulated_station_optics', 'simulated_optics', 'StationOpticsNode',
        ('station.yaml',),
        area=False, publishes=('optical_power',),
        subscribes=tuple('%s/tip_position' % a for a in STATION_AXES)),
    'station_sequencer': NodeSpec(
        'station_sequencer', 'alignment_sequencer', 'StationSequencerNode', ('station.yaml',),
        area=False, publishes=tuple('%s/setpoint' % a for a in STATION_AXES),
        subscribes=('optical_power',)),
    # the fiber array (graph/array.py): three actuators x, y_left, y_right
    'simulated_array_optics': NodeSpec(
        'simulated_array_optics', 'simulated_optics', 'ArrayOpticsNode', ('array.yaml',),
        area=False, publishes=ARRAY_POWERS + ('array_model',),
        subscribes=tuple('%s/tip_position' % a for a in ARRAY_AXES)),
    'array_sequencer': NodeSpec(
        'array_sequencer', 'alignment_sequencer', 'ArraySequencerNode', ('array.yaml',),
        area=False, publishes=tuple('%s/setpoint' % a for a in ARRAY_AXES),
        subscribes=ARRAY_POWERS),
    COMPENSATOR: NodeSpec(COMPENSATOR, COMPENSATOR, 'HysteresisCompensatorNode',
                          ('compensator.yaml', 'models/compensator_model.yaml'),
                          publishes=('feedforward_voltage', 'reference'),
                          subscribes=('setpoint',)),
    CONTROLLER: NodeSpec(CONTROLLER, CONTROLLER, 'FuzzyPidControllerNode',
                         ('controller.yaml',), publishes=('feedback_voltage',
                                                          'controller_state'),
                         subscribes=('reference', 'displacement')),
    DRIVER: NodeSpec(DRIVER, DRIVER, 'ActuatorDriverNode', ('driver.yaml',), lifecycle=True,
                     publishes=('drive_voltage',),
                     subscribes=('feedforward_voltage', 'feedback_voltage')),
    # the hardware rig's amplifier (graph/hardware_rig.py): one MDT693B, both axes
    'mdt693b_driver': NodeSpec('mdt693b_driver', 'actuator_driver', 'ActuatorDriverNode',
                               ('hardware_rig.yaml',), lifecycle=True, area=False,
                               publishes=('x/drive_voltage', 'y/drive_voltage'),
                               subscribes=('x/feedforward_voltage', 'y/feedforward_voltage')),
    'power_meter': NodeSpec('power_meter', 'power_meter', configs=('hardware.yaml',),
                            area=False, publishes=('optical_power',)),
    # hostable: the composed station records in-process (nodes/bag_recorder.py)
    RECORDER: NodeSpec(RECORDER, RECORDER, 'BagRecorder', configs=('recorder.yaml',)),
    LIFECYCLE_MANAGER: NodeSpec(LIFECYCLE_MANAGER, LIFECYCLE_MANAGER,
                                configs=('lifecycle_manager.yaml',)),
    # reads the graph's topics (a parameter, graph/live.py), publishes none
    LIVE_VIEW: NodeSpec(LIVE_VIEW, LIVE_VIEW, configs=('live_view.yaml',), area=False),
    # the run catalogue (graph/catalog.py, docs/records.md): reads, publishes none
    RUN_CATALOG: NodeSpec(RUN_CATALOG, RUN_CATALOG, configs=('records.yaml',), area=False,
                          subscribes=('alignment_state',)),
}
#: The topics that carry a command or a drive to an actuator, each with the one node of
#: an axis meant to publish it: a second publisher (another graph's) is a conflict
#: (:func:`fiber_align.graph.endpoints.extra_publishers`; the driver holds).
DRIVES = {t: n for t in ('feedforward_voltage', 'feedback_voltage', 'reference',
                         'drive_voltage')
          for n in (COMPENSATOR, CONTROLLER, DRIVER) if t in NODES[n].publishes}
#: Nodes a composed process can host: ``--nodes`` name -> spec, in build order.
HOSTABLE = {k: v for k, v in NODES.items() if v.node_class}


def provided_topics(node, namespace):
    """
    Return the fully qualified topics ``node`` publishes when it lives in ``namespace``.

    The topics a composed process delivers in-process (its
    :class:`~fiber_align.nodes.ros.bus.LocalBus`), which an in-process recorder reads
    from the bus rather than from DDS.
    """
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return tuple(t if t.startswith('/') else ns + '/' + t for t in NODES[node].publishes)


#: Per-area params files, in the order they are merged (names in ``config/``): the
#: configs of the 1-D graph's nodes, plant first.
AREA_FILES = tuple(f for n in (PLANT, CONTROLLER, COMPENSATOR, DRIVER, SEQUENCER, RECORDER,
                               SCENARIO_RUNNER, LIFECYCLE_MANAGER)
                   for f in NODES[n].configs if NODES[n].area)
#: Area files a checkout may not have yet (skipped when missing).
OPTIONAL_FILES = ()
#: Graph-wide params file, merged after the per-area files.
GRAPH_FILE = 'fiber_align.yaml'

#: The 1-D graph's ``scenario`` values (the one list: :mod:`fiber_align.simulation.scenarios`).
SCENARIOS = GRAPH_SCENARIOS

#: Remappings applied to every process (``from``, ``to``); the nodes use the graph's
#: relative names as they are, so there are none today.
REMAPPINGS = ()
#: The topics a user commands (``ros2 topic pub --once``, which sends once the first reader
#: matched): each keeps exactly one reader in every graph, the loop's; the live view and
#: the recorders read what the loop accepted (``reference``) instead (issue 39).
COMMANDS = ('setpoint',)


def is_command(topic):
    """Return True for a topic of :data:`COMMANDS` (any namespace: ``x/setpoint``)."""
    return topic.rpartition('/')[2] in COMMANDS


#: What the scenario runner publishes in the open-loop experiment (it drives the driver).
OPEN_LOOP = ('feedforward_voltage', 'feedback_voltage')


def expected_endpoints(graph, observed=()):
    """
    Return ``{topic: (publishers, subscribers)}`` (at least) the running graph must have.

    From :data:`NODES`: the topics its nodes publish and read, only those some node, the
    observer or the recorder (its ``topics``, when the graph records) reads. A reader
    hosted in one process with the topic's publisher reads it in-process (``LocalBus``),
    not as a DDS subscription.

    :param graph: a 1-D :class:`~fiber_align.graph.description.Graph`.
    :param observed: the topics the observer subscribes to.
    """
    def publishes(node):
        if node == SCENARIO_RUNNER:
            return OPEN_LOOP if graph.scenario == 'hysteresis-experiment' else ('setpoint',)
        return NODES[node].publishes if node in NODES else ()
    pubs, subs = {}, {t: 1 for t in observed}
    for p in graph.processes:
        own = {t for n in p.nodes for t in publishes(n)}
        for n in p.nodes:
            for t in publishes(n):
                pubs[t] = pubs.get(t, 0) + 1
            for t in NODES[n].subscribes if n in NODES else ():
                if not (len(p.nodes) > 1 and t in own):
                    subs[t] = subs.get(t, 0) + 1
    out = {t: (pubs.get(t, 0), n) for t, n in subs.items()}
    if graph.sync_mode == 'lockstep':
        out['/clock'] = (1, 0)
    # a recorder hosted beside a topic's publisher takes it from the bus, not from DDS
    beside = {t for p in graph.processes if RECORDER in p.nodes for n in p.nodes
              for t in publishes(n)}
    recorded = {t.lstrip('/') for t in (graph.node_params(RECORDER).get('topics', ())
                                        if graph.record else ())} - beside
    return {k: (p, s + (1 if p and k.lstrip('/') in recorded else 0))
            for k, (p, s) in out.items()}
