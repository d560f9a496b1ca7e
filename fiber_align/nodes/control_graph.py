# SPDX-License-Identifier: Apache-2.0
"""
``control_graph``: several fiber_align nodes in one process (the composed graph).

The analogue of a component container for a pip-installed rclpy, which has no
``rclcpp_components``: ``control_graph --nodes simulated_actuator,hysteresis_compensator,
fuzzy_pid_controller,actuator_driver --ros-args --params-file F ...`` builds each named
node (each keeps its own name and reads its own params-file section) and spins them on
one executor. Messages between the hosted nodes go through a
:class:`~fiber_align.nodes.ros.bus.LocalBus`: a direct call instead of a round trip
through DDS serialisation and the executor, while every message is still published to
DDS for outside subscribers (the recorder, ``ros2 topic echo``). A realtime control
period is then one timer callback of the plant that runs the compensator, the
controller and the driver in turn (docs/ros_interface.md, "Composed graph").

Remapping of the hosted nodes' topics is not supported; a namespace (``-r __ns:=/name``)
is, and a hosted node may live in a namespace below it: ``--nodes x/rig_actuator,...,
y/rig_actuator,...,simulated_optics_2d`` hosts the two-axis rig in one process
(``/rig/x/simulated_actuator``, ..., ``/rig/simulated_optics_2d``), the bus keyed by
fully qualified topic names.
"""

import argparse
import importlib
import sys

from rclpy.executors import ExternalShutdownException
from rclpy.utilities import remove_ros_args

from fiber_align.graph import registry
from fiber_align.nodes.ros import runtime as c
from fiber_align.nodes.ros.bus import LocalBus
from fiber_align.nodes.ros.scheduling import node_priority
from fiber_align.nodes.ros.sender import Sender
from fiber_align.nodes.ros.teardown import finish

#: Nodes a composed process can host: ``--nodes`` name -> (module, class), in build
#: order (the order of in-process delivery): the graph description's registry.
HOSTABLE = {n: ('fiber_align.nodes.' + spec.executable, spec.node_class)
            for n, spec in registry.HOSTABLE.items()}
DEFAULT_NODES = ('simulated_actuator', 'hysteresis_compensator', 'fuzzy_pid_controller',
                 'actuator_driver')


def parse_nodes(argv):
    """
    Return the node names of the command line (ROS arguments removed), in build order.

    A name may carry a sub-namespace (``x/rig_actuator``). Build order: the
    sub-namespaces in their order of first mention, within one the registry's order
    (the order of in-process delivery).

    :raises SystemExit: (exit 2) an unknown node name, with the allowed ones.
    """
    ap = argparse.ArgumentParser(prog='control_graph', description=__doc__.strip().split(
        '\n')[0])
    ap.add_argument('--nodes', default=','.join(DEFAULT_NODES),
                    help='comma-separated node names, from: %s' % ', '.join(HOSTABLE))
    a = ap.parse_args(argv)
    names = [n.strip() for n in a.nodes.split(',') if n.strip()]
    bad = [n for n in names if n.rpartition('/')[2] not in HOSTABLE
           or not all(part.isidentifier() for part in n.split('/'))]
    if bad or not names or len(set(names)) != len(names):
        ap.error('--nodes %r: give each of %s at most once (per sub-namespace: x/name)'
                 % (a.nodes, ', '.join(HOSTABLE)))
    subs = list(dict.fromkeys(n.rpartition('/')[0] for n in names))
    order = list(HOSTABLE)
    return sorted(names, key=lambda n: (subs.index(n.rpartition('/')[0]),
                                        order.index(n.rpartition('/')[2])))


def ros_arguments(argv):
    """
    Return ``(namespace, args)``: the process's ``__ns`` remap and its other ROS arguments.

    :param argv: the command line.
    :returns: the namespace (``'/'`` without a remap) and the ``--ros-args`` items
        without the namespace remap, for the nodes hosted in a sub-namespace (a global
        ``__ns`` remap would override the namespace they are given).
    """
    ros, inside = [], False
    for item in argv[1:]:
        if item == '--ros-args':
            inside = True
        elif item == '--' and inside:
            inside = False
        elif inside:
            ros.append(item)
    ns, out, i = '/', [], 0
    while i < len(ros):
        if ros[i] in ('-r', '--remap') and i + 1 < len(ros) and \
                ros[i + 1].startswith('__ns:='):
            ns = '/' + ros[i + 1][len('__ns:='):].strip('/')
            i += 2
            continue
        out.append(ros[i])
        i += 1
    return ns, out


def build(names, bus=None, argv=()):
    """
    Build the named nodes on one :class:`~fiber_align.nodes.ros.bus.LocalBus`.

    :param names: node names from :data:`HOSTABLE`, each maybe below a sub-namespace
        (``x/rig_actuator``), in build order (after ``rclpy.init``).
    :param argv: the process's command line (its namespace and ROS arguments, which a
        node in a sub-namespace is given as its own: :func:`ros_arguments`).
    :returns: ``(nodes, bus)``.
    """
    bus = bus if bus is not None else LocalBus()
    ns, ros = ros_arguments(list(argv) or ['control_graph'])
    specs = []
    for n in names:
        sub, _, base = n.rpartition('/')
        node_ns = ns.rstrip('/') + '/' + sub if sub else ns
        kw = dict(namespace=node_ns, use_global_arguments=False,
                  cli_args=['--ros-args'] + ros) if sub else {}
        specs.append((base, node_ns, kw, importlib.import_module(HOSTABLE[base][0])))
    for base, node_ns, _, _ in specs:
        bus.provide(*registry.provided_topics(base, node_ns))
    nodes = []
    try:
        for base, _, kw, m in specs:
            nodes.append(getattr(m, HOSTABLE[base][1])(bus=bus, **kw))
    except Exception:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes, bus


def is_realtime(nodes):
    """Return True unless the hosted nodes run in lockstep."""
    for node in nodes:
        if node.has_parameter('sync_mode'):
            return node.get_parameter('sync_mode').value == 'realtime'
    return True


def publish_thread(nodes):
    """Return True when a hosted node asks for the publish thread (``publish_thread``)."""
    return any(n.has_parameter('publish_thread') and n.get_parameter('publish_thread').value
               for n in nodes)


def main(args=None):
    """Run the composed graph (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    argv = sys.argv if args is None else ['control_graph'] + list(args)
    names = parse_nodes(remove_ros_args(argv)[1:])
    stop = c.init(argv)
    nodes = []
    bus = LocalBus()
    bus.sender = Sender()
    try:
        nodes, _ = build(names, bus, argv)
        realtime = is_realtime(nodes)
        # realtime: the DDS publishes leave the control thread (ros/sender.py); lockstep
        # has no deadline and keeps them on the executor's thread
        if realtime and publish_thread(nodes):
            if bus.sender.start():
                for n in nodes:         # their log lines too (/rosout is a DDS publish)
                    bus.sender.queue_logs(n)
            else:
                nodes[0].get_logger().warn('DDS publishes stay on the control thread: %s'
                                           % bus.sender.error)
        c.spin(nodes, realtime=realtime, priority=node_priority(nodes), stop=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except c.NODE_ERRORS as exc:
        return c.refuse('control_graph', exc)
    finally:
        left = bus.sender.stop()
        if left and nodes:
            nodes[0].get_logger().error('%d messages not handed to DDS at exit' % left)
        finish(nodes, stop)
    return c.exit_code(stop)


if __name__ == '__main__':
    sys.exit(main())
