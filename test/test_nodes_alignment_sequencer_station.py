# SPDX-License-Identifier: Apache-2.0
"""
The station's own nodes in one process: bad input is refused, never a crash; pairing holds.

``simulated_station_optics`` (``simulated_optics``) and ``station_sequencer`` in lockstep,
fed by a harness: a NaN or empty tip position gives a NaN reading (the detector's
averaging is not poisoned: the next reading equals the offline link's), the sequencer
answers every sample, also one with an empty displacement and a NaN or negative power,
a read-only parameter is refused with its name, and ``align`` is refused while a
driver is down, naming it.
"""

import math

import pytest

from procs import joint_state, nodes_on_executor, spin_until

import rclpy  # noqa: E402, F401 - a hard dependency of the node tests

from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Bool, Float64  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from fiber_align.graph.registry import STATION_AXES as AXES  # noqa: E402
from fiber_align.nodes.ros.qos import CONTROL_QOS, LATCHED_QOS  # noqa: E402
from fiber_align.plant import station_optics as so  # noqa: E402

pytestmark = pytest.mark.ros
LOCKSTEP = [Parameter('sync_mode', value='lockstep')]


@pytest.fixture()
def station():
    """Both station nodes and a harness on one executor; torn down after the test."""
    from fiber_align.nodes.simulated_optics import StationOpticsNode
    from fiber_align.nodes.alignment_sequencer import StationSequencerNode
    with nodes_on_executor(lambda: StationOpticsNode(parameter_overrides=LOCKSTEP),
                           lambda: StationSequencerNode(parameter_overrides=LOCKSTEP),
                           lambda: Node('harness')) as (ex, nodes):
        yield ex, nodes


def test_bad_tip_positions_give_nan_readings_and_do_not_poison_the_detector(station):
    ex, (optics, _, h) = station
    pub = [h.create_publisher(JointState, a + '/tip_position', CONTROL_QOS) for a in AXES]
    got = []
    h.create_subscription(Float64, 'optical_power', lambda m: got.append(m.data),
                          CONTROL_QOS)
    assert spin_until(ex, lambda: all(p.get_subscription_count() for p in pub), 10.0)
    good = (40e-6, 25e-6, 22e-6, 41e-6)
    for first in (math.nan, None, good[0]):
        pub[0].publish(joint_state() if first is None else joint_state(first))
        for p, v in zip(pub[1:], good[1:]):
            p.publish(joint_state(v))
    assert spin_until(ex, lambda: len(got) == 3, 10.0), got
    assert math.isnan(got[0]) and math.isnan(got[1])
    # the third reading is the offline link's first: the bad ones never reached it
    link = so.StationLink.from_params(seed=optics.get_parameter('seed').value,
                                      sample_period_s=optics.period_s)
    assert got[2] == link.measure(2 * optics.period_s, good, optics.period_s)


def test_sequencer_answers_every_sample_refuses_read_only_and_align_while_down(station):
    ex, (_, seq, h) = station
    pub = {t: h.create_publisher(JointState if 'disp' in t else Float64, t, CONTROL_QOS)
           for t in tuple(a + '/displacement' for a in AXES) + ('optical_power',)}
    sp = {a: [] for a in AXES}
    for a in AXES:
        h.create_subscription(Float64, a + '/setpoint', lambda m, a=a: sp[a].append(m.data),
                              CONTROL_QOS)
    assert spin_until(ex, lambda: all(p.get_subscription_count() for p in pub.values()),
                      10.0)
    for x, p in ((None, 1e-10), (32.5e-6, math.nan), (math.inf, -1.0), (32.5e-6, 1e-10)):
        pub['in/x/displacement'].publish(joint_state() if x is None else joint_state(x))
        for a in AXES[1:]:
            pub[a + '/displacement'].publish(joint_state(32.5e-6))
        pub['optical_power'].publish(Float64(data=p))
    assert spin_until(ex, lambda: all(len(v) == 4 for v in sp.values()), 10.0), sp
    assert seq.n == 4 and seq.seq.state == 'IDLE'
    assert all(v == [32.5e-6] * 4 for v in sp.values())      # parked while IDLE
    # every core parameter is read-only: refused with the reason, the value kept
    res = seq.set_parameters([Parameter('search_speed_m_per_s', value=1.0)])[0]
    assert not res.successful and 'read-only' in res.reason, res.reason
    assert seq.get_parameter('search_speed_m_per_s').value == 3.0e-3
    # a driver holding its output: align refused, naming it
    held = h.create_publisher(Bool, 'out/y/drive_held', LATCHED_QOS)
    held.publish(Bool(data=True))
    assert spin_until(ex, lambda: seq.seq.drivers.active is False, 10.0)
    client = h.create_client(Trigger, 'align')
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(ex, future.done, 10.0)
    assert not future.result().success
    assert 'out/y/actuator_driver' in future.result().message
