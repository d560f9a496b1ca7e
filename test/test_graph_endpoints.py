# SPDX-License-Identifier: Apache-2.0
"""
Publishers of the wrong type on a node's topics are named (graph.endpoints).

One graph per set of names (issue 39.1): a graph's node names already on the graph, and
a second publisher of a command or drive topic, are named in one line each.
"""

from fiber_align.graph.arguments import describe
from fiber_align.graph.endpoints import (drive_owners, extra_publishers, foreign_publishers,
                                         graph_names, names_taken, started_first,
                                         starting_marker, surplus_publishers,
                                         suspect_topics, type_name, unconnected)


class Float64:
    """Stands for a generated class: only its module and name matter."""

    __module__ = 'std_msgs.msg._float64'


def test_type_name_is_the_ros_name_of_the_class():
    assert type_name(Float64) == 'std_msgs/msg/Float64'


def test_type_name_of_a_real_message_class():
    from std_msgs.msg import Float64 as Real
    assert type_name(Real) == 'std_msgs/msg/Float64'


def test_a_publisher_of_another_type_is_named_with_both_types():
    found = foreign_publishers(
        {'/setpoint': 'std_msgs/msg/Float64', '/displacement': 'sensor_msgs/msg/JointState'},
        {'/setpoint': [('/fuzzy_pid_controller', 'std_msgs/msg/Float64'),
                       ('/_ros2cli_1234', 'std_msgs/msg/String')],
         '/displacement': [('/simulated_actuator', 'sensor_msgs/msg/JointState')]})
    assert found == ['/setpoint: /_ros2cli_1234 publishes std_msgs/msg/String, read here '
                     'as std_msgs/msg/Float64 (never delivered)']


def test_matching_publishers_and_unknown_topics_give_nothing():
    assert foreign_publishers({'/a': 'std_msgs/msg/Bool'},
                              {'/a': [('/x', 'std_msgs/msg/Bool')],
                               '/b': [('/y', 'std_msgs/msg/String')]}) == []
    assert foreign_publishers({'/a': 'std_msgs/msg/Bool'}, {}) == []


def test_two_wrong_publishers_each_get_a_line_in_a_stable_order():
    found = foreign_publishers({'/a': 'std_msgs/msg/Bool'},
                               {'/a': [('/z', 'std_msgs/msg/String'),
                                       ('/y', 'std_msgs/msg/Int32')]})
    assert [f.split(' ')[1] for f in found] == ['/y', '/z']


def test_only_topics_carrying_another_type_are_suspects():
    expected = {'/setpoint': 'std_msgs/msg/Float64', '/diagnostics':
                'diagnostic_msgs/msg/DiagnosticArray', '/quiet': 'std_msgs/msg/Bool'}
    graph = [('/setpoint', ['std_msgs/msg/Float64', 'std_msgs/msg/String']),
             ('/diagnostics', ['diagnostic_msgs/msg/DiagnosticArray']),
             ('/other', ['std_msgs/msg/String'])]
    assert suspect_topics(expected, graph) == ['/setpoint']
    assert suspect_topics(expected, []) == []


def test_a_graph_s_names_taken_by_another_are_named_in_one_line():
    """Issue 39.1: the second graph of one set of names refuses with what it found."""
    g = describe({})
    want = graph_names(g)
    assert ('actuator_driver', '/') in want and ('lifecycle_manager', '/') in want
    assert names_taken(want, [('_ros2cli_daemon_0', '/')], '0') is None
    line = names_taken(want, sorted(want) + [('other', '/')], '7')
    assert '\n' not in line and 'ROS_DOMAIN_ID=7' in line
    assert '/actuator_driver' in line and '(%d of the %d nodes' % (len(want), len(want)) in line
    # the same graph in another namespace owns other names
    assert names_taken(graph_names(describe({'namespace': 'left'})), want, '0') is None


def test_every_machine_s_names_are_its_processes_hosted_nodes():
    rig = graph_names(describe({'rig': 'true'}))
    assert ('actuator_driver', '/rig/x') in rig and ('alignment_sequencer_2d', '/rig') in rig
    station = graph_names(describe({'station': 'true'}))
    assert ('actuator_driver', '/station/out/y') in station
    assert ('mdt693b_driver', '/rig') in graph_names(describe({'rig': 'true',
                                                               'hardware': 'true'}))


def test_drive_topics_name_their_one_owner_per_axis():
    assert drive_owners('/actuator_driver', ['']) == {
        'feedforward_voltage': '/hysteresis_compensator',
        'feedback_voltage': '/fuzzy_pid_controller',
        'reference': '/hysteresis_compensator', 'drive_voltage': '/actuator_driver'}
    rig = drive_owners('/rig/mdt693b_driver', ['x', 'y'])
    assert rig['y/feedforward_voltage'] == '/rig/y/hysteresis_compensator'
    assert rig['x/drive_voltage'] == '/rig/mdt693b_driver' and len(rig) == 8
    assert drive_owners('/rig/x/actuator_driver', [''])['reference'] == \
        '/rig/x/hysteresis_compensator'


def test_a_second_publisher_of_a_drive_topic_is_named():
    owners = {'/feedforward_voltage': '/hysteresis_compensator',
              '/drive_voltage': '/actuator_driver'}
    one = {'/feedforward_voltage': ['/hysteresis_compensator'],
           '/drive_voltage': ['/actuator_driver']}
    assert extra_publishers(owners, one) == []
    # one publisher, whoever it is (a test's probe, the open-loop runner): no conflict
    assert extra_publishers(owners, {'/feedforward_voltage': ['/probe']}) == []
    assert extra_publishers(owners, dict(one, **{'/feedforward_voltage': [
        '/hysteresis_compensator', '/intruder']})) == [
        '/feedforward_voltage: 2 publishers, 1 expected: foreign /intruder (besides '
        '/hysteresis_compensator)']
    # the owner's name twice: a restarted owner's expired writer (or another graph of
    # the same names, refused at its start): not named
    assert extra_publishers(owners, dict(one, **{'/drive_voltage': [
        '/actuator_driver', '/actuator_driver']})) == []
    assert extra_publishers(owners, {'/feedforward_voltage': ['/a', '/b']}) == [
        '/feedforward_voltage: 2 publishers, 1 expected: foreign /a, /b']


def test_a_topic_short_of_an_endpoint_is_unconnected_and_one_more_publisher_is_named():
    expected = {'displacement': (1, 2), 'setpoint': (1, 1), '/clock': (1, 0), 'p': (0, 1)}
    counts = {'displacement': (1, 1), 'setpoint': (2, 1), '/clock': (1, 3), 'p': (4, 1)}
    assert unconnected(expected, counts) == ['displacement']
    assert surplus_publishers(expected, counts) == ['setpoint (2 publishers, expected 1)']
    assert unconnected(expected, dict(counts, displacement=(1, 2))) == []


def test_two_starts_of_one_set_of_names_are_ordered_by_their_markers():
    want = graph_names(describe({}))
    a = starting_marker(want, 1_000_000_000_000, 4321)
    b = starting_marker(want, 1_000_400_000_000, 1234)         # 0.4 s later
    other = starting_marker(graph_names(describe({'namespace': 'left'})), 0, 1)
    assert a.startswith('_fiber_align_starting_') and a != b
    assert a[:34] == b[:34] and a[:34] != other[:34]            # the digest of the names
    listing = [(a, '/'), (b, '/'), (other, '/'), ('talker', '/')]
    line = started_first(b, listing, '7')
    assert 'ROS_DOMAIN_ID=7' in line and '0.40 s before' in line and '4321' in line, line
    assert started_first(a, listing, '7') is None               # the earlier one starts
    assert started_first(b, [(b, '/'), (other, '/')], '7') is None
