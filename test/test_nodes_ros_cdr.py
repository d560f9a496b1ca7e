# SPDX-License-Identifier: Apache-2.0
"""The CDR of an rclpy message for a bag, without DDS (``nodes.ros.cdr``)."""

import numpy as np
import pytest

from fiber_align.analysis import bag as bagio
from fiber_align.nodes.ros.cdr import encoder


def _messages():
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, String
    js = JointState(name=['bimorph_tip'], position=[1.25e-5], velocity=[-0.125],
                    effort=[])
    js.header.stamp = Time(sec=7, nanosec=123456789)
    js.header.frame_id = 'tip'
    diag = DiagnosticArray(status=[DiagnosticStatus(
        level=b'\x01', name='/station/in/x/actuator_driver', message='m',
        values=[KeyValue(key='cycle.samples', value='1000')])])
    return [(js, 'sensor_msgs/msg/JointState'), (Float64(data=-3.5e-6),
                                                 'std_msgs/msg/Float64'),
            (String(data='{"state": "TRACKING"}'), 'std_msgs/msg/String'),
            (Clock(clock=Time(sec=3, nanosec=1000000)), 'rosgraph_msgs/msg/Clock'),
            (diag, 'diagnostic_msgs/msg/DiagnosticArray')]


@pytest.mark.parametrize('index', range(5))
def test_the_bytes_decode_to_the_message_in_rclpy_and_strictly_in_rosbags(index):
    from rclpy.serialization import deserialize_message
    msg, msgtype = _messages()[index]
    ts = bagio.typestore()
    enc = encoder(ts, msgtype, type(msg))
    data = bytes(enc(msg))
    assert deserialize_message(data, type(msg)) == msg
    back = ts.deserialize_cdr(data, msgtype)    # raises on a length that is off
    if msgtype.endswith('JointState'):
        assert back.header.stamp.nanosec == 123456789 and back.name == ['bimorph_tip']
        assert np.array_equal(back.position, [1.25e-5])
        assert np.array_equal(back.velocity, [-0.125]) and back.effort.size == 0
    # a byte field rosbags cannot take as rclpy gives it: rclpy's route, cut exactly
    assert bool(enc.fallback) == msgtype.endswith('DiagnosticArray')


def test_later_messages_change_their_bytes_as_the_fields_change():
    from std_msgs.msg import Float64
    enc = encoder(bagio.typestore(), 'std_msgs/msg/Float64', Float64)
    seen = [bytes(enc(Float64(data=v))) for v in (0.0, 1.5, -2.0)]
    assert len(set(seen)) == 3 and not enc.fallback
