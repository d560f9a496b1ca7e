# SPDX-License-Identifier: Apache-2.0
"""Publishers of the wrong type on a node's topics are named (graph.endpoints)."""

from fiber_align.graph.endpoints import foreign_publishers, suspect_topics, type_name


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
