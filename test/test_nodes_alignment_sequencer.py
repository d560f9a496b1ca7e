# SPDX-License-Identifier: Apache-2.0
"""
The alignment_sequencer node in lockstep reproduces the offline sequencer sample by sample.

A harness node plays the plant (the first-order stand-in loop plus the optics model):
it publishes displacement i and optical power i, waits for setpoint i, steps the loop.
The node is driven through its ``align`` and ``switch`` services; its setpoints must
equal those of the pure core run offline on the same inputs.
"""


import pytest

from procs import spin_until

import rclpy  # noqa: E402 - a hard dependency of the node tests

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, String  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402

from fiber_align.simulation import alignment_bench as ab  # noqa: E402
from fiber_align.alignment import sequencer as sq  # noqa: E402
from fiber_align.control.trajectory import stamp_to_s  # noqa: E402
from fiber_align.nodes.ros.qos import CONTROL_QOS  # noqa: E402

pytestmark = pytest.mark.ros


def s_to_stamp(t_s):
    """Return float seconds as a builtin_interfaces/Time (nanosecond exact for t >= 0)."""
    from builtin_interfaces.msg import Time
    ns = int(round(t_s * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


SLOT = 30e-6
PERIOD = 1e-3


class Harness(Node):
    """Lockstep plant stand-in: one displacement + power per received setpoint."""

    def __init__(self, bench):
        """Wire the topics and service clients."""
        super().__init__('align_harness')
        self.bench = bench
        self.pub_y = self.create_publisher(JointState, 'displacement', CONTROL_QOS)
        self.pub_p = self.create_publisher(Float64, 'optical_power', CONTROL_QOS)
        self.create_subscription(Float64, 'setpoint', self._on_sp, CONTROL_QOS)
        self.create_subscription(String, 'alignment_state', self._on_state, 10)
        self.cli_align = self.create_client(Trigger, 'align')
        self.cli_switch = self.create_client(SetBool, 'switch')
        self.setpoints = []
        self.states = []
        self.k = 0

    def publish_sample(self):
        """Publish sample k (displacement and power at t_k)."""
        b = self.bench
        t = self.k * PERIOD
        p = b.link.measure(t, b.loop.position_m, PERIOD)
        msg = JointState(name=['bimorph_tip'], position=[b.loop.y_meas])
        msg.header.stamp = s_to_stamp(t)
        self.inputs.append((t, b.loop.y_meas, p))
        self.pub_y.publish(msg)
        self.pub_p.publish(Float64(data=p))

    def _on_sp(self, msg):
        self.setpoints.append(msg.data)
        self.bench.loop.step(msg.data)
        self.k += 1
        if self.k < self.n_target:
            self.publish_sample()

    def _on_state(self, msg):
        self.states.append(msg.data)


def test_node_lockstep_matches_offline_core():
    from fiber_align.nodes.alignment_sequencer import AlignmentSequencerNode
    rclpy.init()
    ex = SingleThreadedExecutor()
    node = harness = None
    try:
        node = AlignmentSequencerNode(
            parameter_overrides=[Parameter('sync_mode', value='lockstep')])
        bench = ab.build(seed=9, loop=ab.FirstOrderLoop(seed=9), slot_m=SLOT, record=False)
        harness = Harness(bench)
        harness.inputs = []
        ex.add_node(node)
        ex.add_node(harness)
        assert spin_until(ex, lambda: harness.cli_align.service_is_ready()
                          and harness.pub_y.get_subscription_count() > 0
                          and harness.pub_p.get_subscription_count() > 0, 10.0)
        # 20 idle samples, then align, then run to 150 samples
        harness.n_target = 20
        harness.publish_sample()
        assert spin_until(ex, lambda: len(harness.setpoints) >= 20, 20.0)
        fut = harness.cli_align.call_async(Trigger.Request())
        assert spin_until(ex, fut.done, 10.0) and fut.result().success
        harness.n_target = 150
        harness.publish_sample()
        assert spin_until(ex, lambda: len(harness.setpoints) >= 150, 60.0)
        assert node.seq.state == sq.TRACKING, node.seq.fault_reason
        assert any('"TRACKING"' in s for s in harness.states)
        assert bench.link.loss_db(harness.k * PERIOD, bench.loop.position_m) < 0.1

        # the pure core, offline, on the same inputs (times through the ns stamp) gives
        # the same setpoints
        core = sq.Sequencer()
        offline = []
        for i, (t, y, p) in enumerate(harness.inputs[:150]):
            if i == 20:
                core.align()
            offline.append(core.update(stamp_to_s(s_to_stamp(t)), y, p))
        assert offline == harness.setpoints[:150]
    finally:
        for n in (node, harness):
            if n is not None:
                ex.remove_node(n)
                n.destroy_node()
        ex.shutdown()
        rclpy.try_shutdown()
