# SPDX-License-Identifier: Apache-2.0
"""
The ROS graph's endpoints as a node sees them: pure checks, no rclpy.

A publisher whose type differs from the type a node subscribes with never reaches that
node: DDS does not match the two, and neither side hears of it. :func:`foreign_publishers`
names them, so a node can put them on ``/diagnostics`` (a WARN) instead of waiting in
silence.
"""

import hashlib

from fiber_align.graph.params import DRIVER, GraphError
from fiber_align.graph.registry import DRIVES


#: The name the graph's listing gives a publisher whose node it does not know yet.
UNKNOWN = '_NODE_NAME_UNKNOWN_'


class NamesTaken(GraphError):
    """Another graph owns a graph's node names (:func:`names_taken`): nothing may start."""


def type_name(msg_type):
    """
    Return the ROS name of a message class, e.g. ``'std_msgs/msg/Float64'``.

    :param msg_type: a generated rosidl Python class (its module is ``<pkg>.msg._<name>``).
    """
    pkg, kind = msg_type.__module__.split('.')[:2]
    return '%s/%s/%s' % (pkg, kind, msg_type.__name__)


def suspect_topics(expected, names_and_types):
    """
    Return the subscribed topics on which the graph carries a type other than expected.

    One listing of the graph's topics is far cheaper than the endpoints of every topic
    (each publisher of ``/diagnostics`` comes with its QoS), so only these are looked up.

    :param expected: ``{topic: type name}``: the node's own subscriptions.
    :param names_and_types: ``[(topic, [type name, ...]), ...]`` as rclpy's
        ``get_topic_names_and_types`` (publishers' and subscribers' types together).
    :returns: the sorted topics to look up with :func:`foreign_publishers`.
    """
    graph = dict(names_and_types)
    return sorted(t for t, want in expected.items() if set(graph.get(t, ())) - {want})


def foreign_publishers(expected, publishers):
    """
    Return one line for each publisher of a type other than the one subscribed with.

    :param expected: ``{topic: type name}``: the node's own subscriptions.
    :param publishers: ``{topic: [(node, type name), ...]}``: the graph's publishers of
        those topics (``node`` fully qualified, e.g. ``'/outside_client'``).
    :returns: sorted lines such as ``"/setpoint: /outside_client publishes
        std_msgs/msg/String, read here as std_msgs/msg/Float64 (never delivered)"``.
    """
    out = set()
    for topic, want in expected.items():
        for node, got in publishers.get(topic, ()):
            if got != want:
                out.add('%s: %s publishes %s, read here as %s (never delivered)'
                        % (topic, node, got, want))
    return sorted(out)


def node_fqn(name, namespace):
    """Return the fully qualified name of node ``name`` in ``namespace`` (``/rig/x``, ``/``)."""
    return '%s/%s' % (namespace.rstrip('/'), name)


def graph_names(graph):
    """
    Return the ``(name, namespace)`` of every node a graph description starts.

    :param graph: any graph of :mod:`fiber_align.graph` (its processes' hosted nodes).
    """
    return {h for p in graph.processes for h in p.hosted(graph.namespace)}


def names_taken(expected, listing, domain):
    """
    Return one line when nodes of the graph's names are on the graph already, else None.

    Two graphs of one set of names in one domain share every topic and service: the
    second's commands and lifecycle calls reach the first's nodes. So the second starts
    none of its nodes.

    :param expected: the ``(name, namespace)`` pairs the graph starts (:func:`graph_names`).
    :param listing: ``(name, namespace)`` pairs on the graph (rclpy's
        ``get_node_names_and_namespaces``).
    :param domain: the ``ROS_DOMAIN_ID`` looked in (for the line).
    """
    taken = sorted(node_fqn(n, ns) for n, ns in set(expected) & set(map(tuple, listing)))
    if not taken:
        return None
    return ('another graph owns these names on ROS_DOMAIN_ID=%s: %s (%d of the %d nodes '
            'of this graph); nothing started: stop it, or start this one in another '
            'namespace or ROS_DOMAIN_ID' % (domain, ', '.join(taken), len(taken),
                                            len(set(expected))))


#: The node name a starting graph's probe takes: ``<STARTING><digest>_<t_ms>_<pid>``
#: (:func:`starting_marker`); hidden (``_``), so ``ros2 node list`` shows it only with ``-a``.
STARTING = '_fiber_align_starting_'
#: hex digits of the names' digest in a start marker
DIGEST_LEN = 12


def starting_marker(expected, t_ns, pid):
    """
    Return the node name of a start of the names ``expected``, begun at ``t_ns`` by ``pid``.

    The digest names the set of ``(name, namespace)`` pairs: two starts of one set of
    names (two ``ros2 launch`` of one graph at the same moment, when neither graph's
    nodes exist yet to be seen) carry the same digest, and the start time and pid order
    them.
    """
    digest = hashlib.sha1(repr(sorted(set(expected))).encode()).hexdigest()[:DIGEST_LEN]
    return '%s%s_%d_%d' % (STARTING, digest, int(t_ns) // 1_000_000, int(pid))


def _start_key(name):
    t_ms, pid = name.rsplit('_', 2)[-2:]
    return int(t_ms), int(pid)


def started_first(mine, listing, domain):
    """
    Return one line when a start of the same names began before ``mine``, else None.

    :param mine: this start's :func:`starting_marker`.
    :param listing: ``(name, namespace)`` pairs on the graph.
    :param domain: the ``ROS_DOMAIN_ID`` looked in (for the line).
    """
    same = mine[:len(STARTING) + DIGEST_LEN] + '_'
    earlier = sorted((_start_key(n), n) for n, _ in listing
                     if n.startswith(same) and n != mine and _start_key(n) < _start_key(mine))
    if not earlier:
        return None
    (t_ms, pid), _ = earlier[0]
    return ('another graph of these names started on ROS_DOMAIN_ID=%s %.2f s before this one '
            '(process %d, its nodes not up yet); nothing started: stop it, or start this one '
            'in another namespace or ROS_DOMAIN_ID'
            % (domain, (_start_key(mine)[0] - t_ms) / 1000.0, pid))


def extra_publishers(owners, publishers):
    """
    Return one line per topic that has more than its one publisher, naming the others.

    A command or drive topic has one publisher in a graph (:data:`~.registry.DRIVES`):
    a second one (another graph's controller, compensator or driver, a client) mixes its
    values into the loop's. A second one of the owner's own name is not named: it is a
    restarted owner's writer whose process died (DDS keeps it until its lease ends), or
    another graph of the same names, which its start refuses (:func:`names_taken`).

    :param owners: ``{topic: node}``: the node meant to publish each topic (fully
        qualified).
    :param publishers: ``{topic: [node, ...]}``: the publishers on the graph (fully
        qualified names; a name twice: two nodes of that name).
    :returns: sorted lines such as ``"/feedforward_voltage: 2 publishers, 1 expected:
        foreign /intruder (besides /hysteresis_compensator)"``.
    """
    out = []
    for topic, owner in owners.items():
        got = sorted(publishers.get(topic, ()))
        others = [n for n in got if n != owner]
        if len(got) <= 1 or not others:
            continue
        note = ' (besides %s)' % owner if len(others) < len(got) else ''
        out.append('%s: %d publishers, 1 expected: foreign %s%s'
                   % (topic, len(got), ', '.join(others), note))
    return sorted(out)


def unconnected(expected, counts):
    """
    Return the topics with fewer publishers or subscribers than ``expected``.

    :param expected: ``{topic: (publishers, subscribers)}`` the running graph must have
        at least (:func:`~.registry.expected_endpoints`).
    :param counts: ``{topic: (publishers, subscribers)}`` on the domain.
    """
    return [t for t, want in expected.items() if any(n < w for n, w in zip(counts[t], want))]


def surplus_publishers(expected, counts):
    """
    Return one line per topic with more publishers than ``expected`` (exactly; 0: any).

    A topic of the graph with a publisher more is written by another graph on the domain.
    Arguments as :func:`unconnected`; lines such as ``"/setpoint (2 publishers, expected
    1)"``.
    """
    return ['%s (%d publishers, expected %d)' % (t, counts[t][0], p)
            for t, (p, _) in expected.items() if p and counts[t][0] > p]


def drive_owners(driver, axes):
    """
    Return ``{topic: owner}`` of the command and drive topics of a driver's axes.

    :param driver: the driver's fully qualified name (``/actuator_driver``,
        ``/rig/mdt693b_driver``).
    :param axes: its axes (``''``: the one unnamed axis; ``x``: topics ``x/...``).
    :returns: relative topic names (as the driver resolves them) -> the fully qualified
        name of the node meant to publish each (:data:`~.registry.DRIVES`; the drive: the
        driver itself).
    """
    ns = driver.rpartition('/')[0]
    out = {}
    for a in axes:
        base = '/'.join(x for x in (ns, a) if x)
        for topic, node in DRIVES.items():
            out['%s/%s' % (a, topic) if a else topic] = \
                driver if node == DRIVER else '%s/%s' % (base, node)
    return out
