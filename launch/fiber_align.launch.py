# SPDX-License-Identifier: Apache-2.0
"""
Launch the fiber_align graph on the simulated actuator, or on the hardware bench.

``ros2 launch fiber_align fiber_align.launch.py [name:=value ...]``; ``ros2 launch -s``
lists the arguments. The processes, node names, params files and remappings come from
:mod:`fiber_align.graph.description` (the one description of the graph, shared with
``bringup``); this file only turns that description into launch_ros ``Node`` actions.
Every process reads one params file, the merge of ``config/*.yaml`` (per-area files, then
``fiber_align.yaml``), ``params_file`` and the arguments below, written to a temporary
directory that is removed at shutdown. The processes get the graph's environment
(:func:`fiber_align.graph.description.dds_environment`: the Fast DDS profile of
``config/fastdds_profile.xml``) unless the user's sets it; the user's ROS discovery
environment is kept as it is (docs/network.md). ``lifecycle_manager`` brings
the driver to active; Ctrl-C (SIGINT) stops every process, and the recorder finalises
its bag. With a scenario, the launch shuts down when the process hosting
``scenario_runner`` exits (the scenario is over); any other process that exits leaves
the rest running (the driver's watchdog holds the actuator safe, and the graph recovers
when the node is back).

``rig:=true`` starts the two-axis rig instead (:mod:`fiber_align.graph.rig`: the
actuator graphs ``/<namespace>/x`` and ``/<namespace>/y``, the optics and the 2-D
sequencer, namespace ``rig`` unless given; ``seed`` is the run seed of the plants, the
detector and the target, as ``fiber-align simulate --scenario align2d --seed``); call
``/rig/align`` to align. ``model_file``, ``record`` and ``scenario`` are 1-D only.

``hardware:=true [port:=/dev/serial/by-id/...] [visa_resource:=USB0::...::INSTR]``: the
sensorless bench instead (:func:`fiber_align.graph.hardware.build_hardware`: an
MDT693B behind ``actuator_driver``, ``power_meter``, the sequencer on optical power; no
simulated plant); ``sync_mode``, ``controller`` and ``scenario`` do not apply to it. To try
it without hardware, start ``fiber-align emulate`` and pass its ``serial_link`` and
``visa_resource`` (docs/hardware.md). ``rig:=true hardware:=true``: the two-axis rig on
one MDT693B (x and y channels) and a PM100 (:mod:`fiber_align.graph.hardware_rig`).

``station:=true``: the coupled station instead (:mod:`fiber_align.graph.station`: the
actuator graphs ``/<namespace>/in/x`` .. ``/<namespace>/out/y``, the chip's optics and the
station sequencer, namespace ``station`` unless given; ``seed`` as ``fiber-align simulate
--scenario station --seed``; ``record`` records the station's topics); call
``/station/align`` to align.

``live:=true [live_port:=8765] [live_host:=127.0.0.1]`` (any of the graphs above): the
Foxglove live view, a process of its own (:mod:`fiber_align.graph.live`, docs/live_view.md).
"""

import os
import shutil
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler
from launch.actions import SetEnvironmentVariable, Shutdown
from launch.event_handlers import OnShutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from fiber_align.graph import description as graph, rig as graph_rig
from fiber_align.graph import station as graph_station
from fiber_align.graph.hardware import build_hardware
from fiber_align.graph.hardware_rig import build_hardware_rig
from fiber_align.graph.live import check_endpoint, live_settings, with_live
from fiber_align.graph.params import GraphError

#: name, default, description, choices (``None``: any value)
ARGUMENTS = (
    ('namespace', '', 'namespace of every node ("" = none)', None),
    ('composed', str(graph.DEFAULT_COMPOSED).lower(),
     'true: the control nodes in one control_graph process; false: one process per node',
     ['true', 'false']),
    ('sync_mode', '', 'sample clock ("" = as the params files say: realtime)',
     [''] + list(graph.SYNC_MODES)),
    ('controller', '', 'control law ("" = as the params files say: composite)',
     [''] + list(graph.CONTROLLERS)),
    ('params_file', '', 'params file applied after config/fiber_align.yaml', None),
    ('model_file', '', 'PI model params file for hysteresis_compensator ("" = inline)',
     None),
    ('record', '', 'bag directory to record into (must not exist; "" = no recording)', None),
    ('scenario', '', 'setpoint scenario of scenario_runner ("" = as the params files say: '
     'none, the graph waits for setpoints)', [''] + list(graph.SCENARIOS)),
    ('rig', 'false', 'true: the two-axis rig (/rig/x, /rig/y, optics, 2-D sequencer) '
     'instead of the 1-D graph', ['true', 'false']),
    ('station', 'false', 'true: the coupled station (/station/in/x .. /station/out/y, the '
     "chip's optics, the station sequencer) instead of the 1-D graph", ['true', 'false']),
    ('seed', '0', 'rig, station: run seed (plant, detector seeds and target or facets, as '
     'the offline align2d and station)', None),
    ('hardware', 'false', 'true: the sensorless bench (MDT693B + PM100) instead of the '
     'simulated actuator', ['true', 'false']),
    ('port', '', 'hardware: MDT693B serial device ("" = config/hardware.yaml)', None),
    ('visa_resource', '', 'hardware: PM100 VISA resource ("" = config/hardware.yaml)', None),
    ('live', 'false', 'true: the Foxglove live view (ws://live_host:live_port, '
     'docs/live_view.md)', ['true', 'false']),
    ('live_port', '', 'live view TCP port ("" = config/live_view.yaml: 8765)', None),
    ('live_host', '', 'live view address ("" = config/live_view.yaml: 127.0.0.1)', None),
)
#: Arguments the rig does not take (1-D graph only).
ONE_AXIS_ONLY = ('model_file', 'record', 'scenario')
#: Arguments the station does not take.
NOT_STATION = ('model_file', 'scenario')
#: Arguments of the hardware graph only, and the ones it does not take.
HARDWARE_ONLY = ('port', 'visa_resource')
NOT_HARDWARE = ('sync_mode', 'controller', 'scenario')
#: The live view's arguments (every graph), in :func:`with_live`'s order.
LIVE_ARGS = ('live', 'live_port', 'live_host')


def describe(args):
    """Return the graph (1-D, the rig or the hardware bench) for the launch arguments."""
    args = dict(args)
    live = [args.pop(k, '') for k in LIVE_ARGS]
    g = with_live(_describe(args), *live)
    served = live_settings(g)
    if served:                  # a port in use: one line before any process starts
        check_endpoint(*served)
    return g


def _describe(args):
    rig = graph.parse_bool('rig', args.pop('rig'))
    hardware = graph.parse_bool('hardware', args.pop('hardware'))
    station = graph.parse_bool('station', args.pop('station'))
    seed = args.pop('seed')
    hw = {k: args.pop(k) for k in HARDWARE_ONLY}
    if station:
        given = ['rig:=true'] * rig + ['hardware:=true'] * hardware + [
            k for k in NOT_STATION + HARDWARE_ONLY if args.get(k) or hw.get(k)]
        if given:
            raise GraphError('%s: not available with station:=true' % ', '.join(given))
        for k in NOT_STATION:
            args.pop(k)
        return graph_station.build_station(
            namespace=args.pop('namespace') or graph_station.STATION_NAMESPACE, seed=seed,
            **args)
    if rig and hardware:
        return build_hardware_rig_args(args, hw)
    if not hardware and any(hw.values()):
        raise GraphError('%s: only with hardware:=true'
                         % ', '.join(k for k in HARDWARE_ONLY if hw[k]))
    if hardware:
        given = [k for k in NOT_HARDWARE if args.pop(k)]
        if given:
            raise GraphError('%s: not available with hardware:=true' % ', '.join(given))
        return build_hardware(**hw, **args)
    if not rig:
        return graph.build(**args)
    given = [k for k in ONE_AXIS_ONLY if args.pop(k)]
    if given:
        raise GraphError('%s: not available with rig:=true' % ', '.join(given))
    return graph_rig.build_rig(namespace=args.pop('namespace') or graph_rig.RIG_NAMESPACE,
                               seed=seed, **args)


def build_hardware_rig_args(args, hw):
    """Return the hardware rig (``rig:=true hardware:=true``) for the launch arguments."""
    given = [k for k in dict.fromkeys(NOT_HARDWARE + ONE_AXIS_ONLY) if args.pop(k, '')]
    if given:
        raise GraphError('%s: not available with rig:=true hardware:=true' % ', '.join(given))
    return build_hardware_rig(namespace=args.pop('namespace') or graph_rig.RIG_NAMESPACE,
                              **hw, **args)


def launch_setup(context):
    """Build the graph from the launch arguments; return its Node actions."""
    args = {name: LaunchConfiguration(name).perform(context) for name, *_ in ARGUMENTS}
    g = describe(args)
    tmp = tempfile.mkdtemp(prefix='fiber_align_launch_')
    params = g.write_params(os.path.join(tmp, 'params.yaml'))
    actions = [RegisterEventHandler(OnShutdown(
        on_shutdown=lambda event, ctx: shutil.rmtree(tmp, ignore_errors=True)))]
    # the graph's environment (the Fast DDS profile) where the user's environment does
    # not set it: the same as under bringup
    actions += [SetEnvironmentVariable(k, v) for k, v in graph.dds_environment().items()
                if os.environ.get(k) != v]
    for p in g.processes:
        actions.append(Node(
            package=graph.PACKAGE, executable=p.executable, name=p.node_name,
            namespace=_namespace(g.namespace if p.namespace is None else p.namespace),
            arguments=list(p.arguments), parameters=[params],
            remappings=list(g.remappings), output='screen',
            on_exit=[Shutdown(reason='%s exited: the scenario is over' % p.name)]
            if p.ends_graph else None))
    return actions


def _namespace(ns):
    return ('/' + ns) if ns else None


def generate_launch_description():
    """Return the launch description: the arguments and the graph built from them."""
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text,
                               **({'choices': choices} if choices else {}))
         for name, default, text, choices in ARGUMENTS]
        + [OpaqueFunction(function=launch_setup)])
