# SPDX-License-Identifier: Apache-2.0
"""
Launch the fiber_align graph on the simulated actuator, or on the hardware bench.

``ros2 launch fiber_align fiber_align.launch.py [name:=value ...]``; ``ros2 launch -s``
lists the arguments. The processes, node names, params files and remappings come from
:mod:`fiber_align.nodes.graph` (the one description of the graph, shared with
``bringup``); this file only turns that description into launch_ros ``Node`` actions.
Every process reads one params file, the merge of ``config/*.yaml`` (per-area files, then
``fiber_align.yaml``), ``params_file`` and the arguments below, written to a temporary
directory that is removed at shutdown. The processes get the graph's environment
(:func:`fiber_align.nodes.graph.dds_environment`: the Fast DDS profile of
``config/fastdds_profile.xml``) unless the user's sets it. ``lifecycle_manager`` brings
the driver to active; Ctrl-C (SIGINT) stops every process, and the recorder finalises
its bag. With a scenario, the launch shuts down when the process hosting
``scenario_runner`` exits (the scenario is over); any other process that exits leaves
the rest running (the driver's watchdog holds the actuator safe, and the graph recovers
when the node is back).

``hardware:=true [port:=/dev/serial/by-id/...] [visa_resource:=USB0::...::INSTR]``: the
sensorless bench instead (:func:`fiber_align.nodes.graph_hardware.build_hardware`: an
MDT693B behind ``actuator_driver``, ``power_meter``, the sequencer on optical power; no
simulated plant); ``sync_mode``, ``controller`` and ``scenario`` do not apply to it. To try
it without hardware, start ``fiber-align emulate`` and pass its ``serial_link`` and
``visa_resource`` (docs/hardware.md).
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

from fiber_align.nodes import graph
from fiber_align.nodes.graph_hardware import build_hardware

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
    ('hardware', 'false', 'true: the sensorless bench (MDT693B + PM100) instead of the '
     'simulated actuator', ['true', 'false']),
    ('port', '', 'hardware: MDT693B serial device ("" = config/hardware.yaml)', None),
    ('visa_resource', '', 'hardware: PM100 VISA resource ("" = config/hardware.yaml)', None),
)
#: Arguments of the simulated graph only, and of the hardware graph only.
SIMULATED_ONLY = ('sync_mode', 'controller', 'scenario')
HARDWARE_ONLY = ('port', 'visa_resource')


def build_graph(args):
    """Return the graph of the launch arguments (a dict of strings)."""
    hardware = graph.parse_bool('hardware', args.pop('hardware'))
    given = [k for k in (SIMULATED_ONLY if hardware else HARDWARE_ONLY) if args[k]]
    if given:
        raise graph.GraphError('%s do(es) not apply with hardware:=%s'
                               % (', '.join(given), str(hardware).lower()))
    if hardware:
        for k in SIMULATED_ONLY:
            args.pop(k)
        return build_hardware(**args)
    for k in HARDWARE_ONLY:
        args.pop(k)
    return graph.build(**args)


def launch_setup(context):
    """Build the graph from the launch arguments; return its Node actions."""
    args = {name: LaunchConfiguration(name).perform(context) for name, *_ in ARGUMENTS}
    g = build_graph(args)
    tmp = tempfile.mkdtemp(prefix='fiber_align_launch_')
    params = g.write_params(os.path.join(tmp, 'params.yaml'))
    actions = [RegisterEventHandler(OnShutdown(
        on_shutdown=lambda event, ctx: shutil.rmtree(tmp, ignore_errors=True)))]
    # the graph's environment (Fast DDS profile, discovery range) where the user's
    # environment does not set it: the same as under bringup
    actions += [SetEnvironmentVariable(k, v) for k, v in graph.dds_environment().items()
                if os.environ.get(k) != v]
    for p in g.processes:
        actions.append(Node(
            package=graph.PACKAGE, executable=p.executable, name=p.node_name,
            namespace=('/' + g.namespace) if g.namespace else None,
            arguments=list(p.arguments), parameters=[params],
            remappings=list(g.remappings), output='screen',
            on_exit=[Shutdown(reason='%s exited: the scenario is over' % p.name)]
            if p.ends_graph else None))
    return actions


def generate_launch_description():
    """Return the launch description: the arguments and the graph built from them."""
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text,
                               **({'choices': choices} if choices else {}))
         for name, default, text, choices in ARGUMENTS]
        + [OpaqueFunction(function=launch_setup)])
