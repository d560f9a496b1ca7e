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


def _sample_messages():
    """Return the control period's message types, with empty, one- and many-element fields."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension, String
    out = [Float64(data=2.5e-5), String(data=''), String(data='TRACKING ü'),
           Float64MultiArray(), JointState()]
    for n in (1, 3):
        js = JointState(name=['a' * (i + n) for i in range(n)], position=[0.5 * i for i in
                        range(n)], velocity=[], effort=[1.0] * n)
        js.header.stamp.sec, js.header.stamp.nanosec = 12, 34
        js.header.frame_id = 'f' * n
        out.append(js)
        ma = Float64MultiArray(data=[float(i) - 0.25 for i in range(2 * n)])
        ma.layout.dim = [MultiArrayDimension(label='l' * (i + 1), size=1, stride=1)
                         for i in range(n)]
        ma.layout.data_offset = n
        out.append(ma)
    return out


@pytest.mark.parametrize('index', range(9))
def test_the_packer_writes_the_bytes_rosbags_writes(index):
    """Each planned type: the packed CDR equals rosbags' serialisation byte for byte."""
    from fiber_align.graph.endpoints import type_name
    from fiber_align.analysis.bag.packer import packer
    msg = _sample_messages()[index]
    ts, msgtype = bagio.typestore(), type_name(type(msg))
    enc = encoder(ts, msgtype, type(msg))
    reference = bytes(ts.serialize_cdr(enc._adapt(msg) if enc._adapt else msg, msgtype))
    pack = packer(type(msg))
    assert pack is not None and pack(msg) == reference
    assert bytes(enc(msg)) == reference and enc.route == 'packer'
    assert bytes(enc(msg)) == reference        # the planned route after the first check


def test_a_nan_in_the_first_message_keeps_the_fast_route():
    """A derivative's first sample is NaN; NaN != NaN took the topic to rclpy's route."""
    import math
    from std_msgs.msg import Float64MultiArray
    enc = encoder(bagio.typestore(), 'std_msgs/msg/Float64MultiArray', Float64MultiArray)
    data = bytes(enc(Float64MultiArray(data=[1.0, math.nan])))
    assert enc.fallback == '' and enc.route == 'packer'
    back = bagio.typestore().deserialize_cdr(data, 'std_msgs/msg/Float64MultiArray')
    assert back.data[0] == 1.0 and math.isnan(back.data[1])


def test_types_it_cannot_plan_keep_the_rosbags_or_rclpy_route():
    """An octet field (a diagnostic level) is not planned: the existing routes serve."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from fiber_align.analysis.bag.packer import packer
    assert packer(DiagnosticStatus) is None


def test_a_warmed_encoder_leaves_its_first_message_a_fraction_of_a_period():
    """
    ``Encoder.warm`` does the first-use work (rosbags' serialiser, rclpy's) before the loop.

    Each cold case takes a typestore of its own, as a new recorder does: its first message
    pays the generation (6-10 ms here, 44 ms for the process's first); a warmed one's
    first message is the check alone (0.1-0.5 ms). Medians of 3, the cold cases after
    the warm ones so that every process-wide cost is paid before either is timed.
    """
    import time

    from rosbags.typesys import get_typestore, Stores
    from sensor_msgs.msg import JointState
    msg = JointState(name=['bimorph_tip'], position=[1.25e-5], velocity=[-0.125])

    def first(warm):
        store = get_typestore(Stores.ROS2_JAZZY)
        enc = encoder(store, 'sensor_msgs/msg/JointState', JointState)
        if warm:
            enc.warm()
        t0 = time.perf_counter()
        data = enc(msg)
        took = time.perf_counter() - t0
        assert enc.route == 'packer'    # checked on this first message, the fast route kept
        assert store.deserialize_cdr(bytes(data), 'sensor_msgs/msg/JointState').position[
            0] == 1.25e-5
        return took
    first(False)                        # the process's one-time imports and loads
    warm = float(np.median([first(True) for _ in range(3)]))
    cold = float(np.median([first(False) for _ in range(3)]))
    print('first message: warmed %.3f ms, cold %.3f ms' % (warm * 1e3, cold * 1e3))
    assert warm < 0.25 * cold and warm < 2e-3, (warm, cold)
