# SPDX-License-Identifier: Apache-2.0
"""
Launch the fiber_align graph on the simulated actuator, or on the hardware bench.

``ros2 launch fiber_align fiber_align.launch.py [name:=value ...]``; ``ros2 launch -s``
lists the arguments. The graph is :func:`fiber_align.graph.arguments.describe` of the
arguments (the one step from launch arguments to a graph, shared with ``bringup``): its
processes, node names, params files and remappings; this file only turns that
description into launch_ros ``Node`` actions.
Every process reads one params file, the merge of ``config/*.yaml`` (per-area files, then
``fiber_align.yaml``), ``params_file`` and the arguments below, written to a temporary
directory that is removed at shutdown. The processes get the graph's environment
(:func:`fiber_align.graph.description.dds_environment`: the Fast DDS profile of
``config/fastdds_profile.xml``) unless the user's sets it; the user's ROS discovery
environment is kept as it is (docs/network.md). ``lifecycle_manager`` brings
the driver to active; Ctrl-C (SIGINT) stops every process, and the recorder finalises
its bag, also where the launch inherited SIGINT ignored (a script's ``ros2 launch ...
&``). With a scenario, the launch shuts down when the process hosting ``scenario_runner``
exits (the scenario is over). A process that exits before
``lifecycle_manager``'s start-up is done ends the launch with its reason in one line and
exit code 1 (:mod:`fiber_align.graph.startup`); after it, any other process that exits
leaves the rest running (the driver's watchdog holds the actuator safe, and the graph
recovers when the node is back). Every value of the params files is checked against the
range its node declares before any process starts
(:func:`fiber_align.graph.refusals.check_graph`).

``rig:=true`` starts the two-axis rig instead (:mod:`fiber_align.graph.rig`: the
actuator graphs ``/<namespace>/x`` and ``/<namespace>/y``, the optics and the 2-D
sequencer, namespace ``rig`` unless given; ``seed`` is the run seed of the plants, the
detector and the target, as ``fiber-align simulate --scenario align2d --seed``); call
``/rig/align`` to align. ``model_file``, ``record`` and ``scenario`` are 1-D only; on the
1-D graph ``seed`` is the plant's noise seed. Which arguments each graph takes is
:data:`fiber_align.graph.arguments.MACHINES`; any other given is refused in one line.

``hardware:=true [port:=/dev/serial/by-id/...] [visa_resource:=USB0::...::INSTR]``: the
sensorless bench instead (:mod:`fiber_align.graph.hardware`: an
MDT693B behind ``actuator_driver``, ``power_meter``, the sequencer on optical power; no
simulated plant); ``sync_mode``, ``controller`` and ``scenario`` do not apply to it. To try
it without hardware, start ``fiber-align emulate`` and pass its ``serial_link`` and
``visa_resource`` (docs/hardware.md). ``rig:=true hardware:=true``: the two-axis rig on
one MDT693B (x and y channels) and a PM100 (:mod:`fiber_align.graph.hardware_rig`).

``station:=true``: the coupled station instead (:mod:`fiber_align.graph.station`: the
actuator graphs ``/<namespace>/in/x`` .. ``/<namespace>/out/y``, the chip's optics and the
station sequencer, namespace ``station`` unless given; ``seed`` as ``fiber-align simulate
--scenario station --seed``; ``record`` records the station's topics); call
``/station/align`` to align. ``array:=true``: the fiber array (:mod:`fiber_align.graph.
array`: ``/<namespace>/x``, ``y_left``, ``y_right``, the array's optics publishing the
outer channels' ``optical_power`` and ``optical_power_n``, the array sequencer; namespace
``array`` unless given; ``seed`` as ``fiber-align simulate --scenario array --seed``);
call ``/array/align``.

``live:=true [live_port:=8765] [live_host:=127.0.0.1]`` (any of the graphs above): the
Foxglove live view, a process of its own (:mod:`fiber_align.graph.live`, docs/live_view.md).
"""

import os
import shutil
import signal
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler
from launch.actions import SetEnvironmentVariable, Shutdown
from launch.event_handlers import OnProcessExit, OnProcessIO, OnShutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from fiber_align.graph.arguments import ARGUMENTS, describe
from fiber_align.graph.description import dds_environment
from fiber_align.graph.registry import PACKAGE
from fiber_align.graph.startup import StartupWatch
from fiber_align.nodes.ros.owners import refuse_taken

__all__ = ('ARGUMENTS', 'describe', 'generate_launch_description')


def launch_setup(context):
    """Build the graph from the launch arguments; return its Node actions."""
    args = {name: LaunchConfiguration(name).perform(context) for name, *_ in ARGUMENTS}
    g = describe(args)
    refuse_taken(g)         # another graph of these names: one line, nothing started
    tmp = tempfile.mkdtemp(prefix='fiber_align_launch_')
    params = g.write_params(os.path.join(tmp, 'params.yaml'))
    actions = [RegisterEventHandler(OnShutdown(
        on_shutdown=lambda event, ctx: shutil.rmtree(tmp, ignore_errors=True)))]
    # the graph's environment (the Fast DDS profile) where the user's environment does
    # not set it: the same as under bringup
    actions += [SetEnvironmentVariable(k, v) for k, v in dds_environment().items()
                if os.environ.get(k) != v]
    procs = {}
    for p in g.processes:
        node = Node(
            package=PACKAGE, executable=p.executable, name=p.node_name,
            namespace=_namespace(g.namespace if p.namespace is None else p.namespace),
            arguments=list(p.arguments), parameters=[params],
            remappings=list(g.remappings), output='screen',
            on_exit=[Shutdown(reason='%s exited: the scenario is over' % p.name)]
            if p.ends_graph else None)
        procs[node] = p
        actions.append(node)
    return actions + _startup_handlers(procs)


def _startup_handlers(procs):
    """
    Return the handlers that end the launch when a process exits during start-up.

    Until the manager's start-up is done, a process that exits leaves the others waiting
    for it: the launch then ends with its reason in one line (raised: ``ros2 launch``
    logs it, stops every process and exits 1; :class:`StartupWatch`).
    """
    watch = StartupWatch()

    def on_output(event):
        if event.action in procs:
            watch.output(procs[event.action].name, event.text)

    def on_exit(event, context):
        p = procs.get(event.action)
        why = p and watch.exit_reason(p.name, event.returncode, p.ends_graph,
                                      context.is_shutdown)
        if why:
            raise RuntimeError(why)

    return [RegisterEventHandler(OnProcessIO(on_stdout=on_output, on_stderr=on_output)),
            RegisterEventHandler(OnProcessExit(on_exit=on_exit))]


def _namespace(ns):
    return ('/' + ns) if ns else None


def _sigint_as_in_a_terminal():
    """
    Give SIGINT back its default handler where this ``ros2 launch`` inherited it ignored.

    A non-interactive shell starts ``cmd &`` with SIGINT ignored; Python then installs no
    handler, launch's signal manager (a wakeup fd) never hears it, and ``kill -INT`` of
    the launch did nothing: it ran on (a script's background job, 15 s and more).
    """
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def generate_launch_description():
    """Return the launch description: the arguments and the graph built from them."""
    _sigint_as_in_a_terminal()
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text,
                               **({'choices': choices} if choices else {}))
         for name, default, text, choices in ARGUMENTS]
        + [OpaqueFunction(function=launch_setup)])
