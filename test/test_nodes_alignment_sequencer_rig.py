# SPDX-License-Identifier: Apache-2.0
"""
The rig's own nodes in one process: bad input is refused, never a crash; pairing holds.

``simulated_optics_2d`` (``simulated_optics``) and ``alignment_sequencer_2d`` in lockstep, fed by
a harness: a NaN or empty tip position gives a NaN reading (the detector's averaging is
not poisoned: the next reading equals the offline link's), and the sequencer answers
every sample, also one with an empty displacement and a NaN power.
"""

import math

import pytest

from procs import joint_state, nodes_on_executor, spin_until

import rclpy  # noqa: E402, F401 - a hard dependency of the node tests

from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from fiber_align.nodes.ros.qos import CONTROL_QOS  # noqa: E402
from fiber_align.plant import optics2d as o2  # noqa: E402

pytestmark = pytest.mark.ros
LOCKSTEP = [Parameter('sync_mode', value='lockstep')]


@pytest.fixture()
def rig():
    """Both rig nodes and a harness on one executor; torn down after the test."""
    from fiber_align.nodes.alignment_sequencer import RigSequencerNode
    from fiber_align.nodes.simulated_optics import SimulatedOpticsNode
    with nodes_on_executor(lambda: SimulatedOpticsNode(parameter_overrides=LOCKSTEP),
                           lambda: RigSequencerNode(parameter_overrides=LOCKSTEP),
                           lambda: Node('harness')) as (ex, nodes):
        yield ex, nodes


def test_bad_tip_positions_give_nan_readings_and_do_not_poison_the_detector(rig):
    ex, (optics, _, h) = rig
    pub = {a: h.create_publisher(JointState, a + '/tip_position', CONTROL_QOS)
           for a in 'xy'}
    got = []
    h.create_subscription(Float64, 'optical_power', lambda m: got.append(m.data),
                          CONTROL_QOS)
    assert spin_until(ex, lambda: all(p.get_subscription_count() for p in pub.values()),
                      10.0)
    samples = [(math.nan, 30e-6), (None, 30e-6), (31e-6, 29e-6)]
    for x, y in samples:
        pub['x'].publish(joint_state() if x is None else joint_state(x))
        pub['y'].publish(joint_state(y))
    assert spin_until(ex, lambda: len(got) == 3, 10.0), got
    assert math.isnan(got[0]) and math.isnan(got[1])
    # the third reading is the offline link's first: the bad ones never reached it
    link = o2.OpticalLink2D.from_params(None, None, seed=optics.get_parameter('seed').value)
    assert got[2] == link.measure(2 * optics.period_s, 31e-6, 29e-6, optics.period_s)
    assert optics.n == 3


def test_sequencer_answers_every_sample_also_empty_and_nan_ones(rig):
    ex, (_, seq, h) = rig
    pub = {t: h.create_publisher(JointState if 'disp' in t else Float64, t, CONTROL_QOS)
           for t in ('x/displacement', 'y/displacement', 'optical_power')}
    sp = {a: [] for a in 'xy'}
    for a in 'xy':
        h.create_subscription(Float64, a + '/setpoint', lambda m, a=a: sp[a].append(m.data),
                              CONTROL_QOS)
    assert spin_until(ex, lambda: all(p.get_subscription_count() for p in pub.values()),
                      10.0)
    for x, p in ((None, 1e-10), (0.0, math.nan), (math.inf, -1.0), (0.0, 1e-10)):
        pub['x/displacement'].publish(joint_state() if x is None else joint_state(x))
        pub['y/displacement'].publish(joint_state(0.0))
        pub['optical_power'].publish(Float64(data=p))
    assert spin_until(ex, lambda: len(sp['x']) == 4 and len(sp['y']) == 4, 10.0), sp
    assert seq.n == 4 and seq.seq.state == 'IDLE'
    assert sp['x'] == [0.0] * 4 == sp['y']          # parked at (0, 0) while IDLE
