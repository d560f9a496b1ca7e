# SPDX-License-Identifier: Apache-2.0
"""
The ROS graph's endpoints as a node sees them: pure checks, no rclpy.

A publisher whose type differs from the type a node subscribes with never reaches that
node: DDS does not match the two, and neither side hears of it. :func:`foreign_publishers`
names them, so a node can put them on ``/diagnostics`` (a WARN) instead of waiting in
silence.
"""


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
