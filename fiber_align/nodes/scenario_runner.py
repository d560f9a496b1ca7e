# SPDX-License-Identifier: Apache-2.0
"""
``scenario_runner``: the setpoint source of a scenario, one message per sample.

The same node runs a scenario under ``ros2 launch`` and under ``bringup`` (and inside
``control_graph``, where its setpoints reach the compensator in-process, in the same
control period as the sample they answer). Parameters (defaults in
``config/scenario.yaml``):

- ``scenario``: ``step``, ``sine``, ``triangle``, ``staircase`` (the references of
  :mod:`fiber_align.simulation.scenarios`) or ``hysteresis-experiment`` (open loop: the
  0-72 V, 0.1 Hz triangle as ``feedforward_voltage`` with 0 V ``feedback_voltage``).
- ``duration_s``: length (s of sample time); 0: the scenario's own length.
- ``reach_m``: the plant's largest reachable displacement (m), ``bringup`` sets it from
  the plant's parameters as the offline loop does; 0: only the setpoint limits clamp.
- ``setpoint_min_m``, ``setpoint_max_m``: the graph's setpoint limits (m).

For each ``displacement`` sample with stamp t_k (t = t_k - t_0, t_0 the first sample's
stamp) it publishes ``setpoint`` = the reference at t (m), clamped to
``[max(0, setpoint_min_m), min(setpoint_max_m, reach_m)]``; once t reaches the duration
it publishes nothing more, so a lockstep graph holds after exactly ``duration * rate``
commands and a realtime graph holds the last setpoint; with ``exit_when_done`` (set by
the launch file) the process then ends, which ends the launch. ``scenario_state``
(std_msgs/String, latched) is ``running`` and then ``done``.

With ``wait_for_recorder`` (the launch file sets it when it records) that end waits,
at most ``recorder_wait_s``, until ``bag_recorder`` holds what the nodes sent
(:mod:`fiber_align.analysis.recording`, from their ``/diagnostics`` counts): in lockstep
every message, in realtime (the graph keeps running) every topic sent on. A short run
can otherwise end the launch before the recorder has found its publishers.
"""

import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String

from fiber_align.analysis.recording import diag_entry, left_text, recorder_missing
from fiber_align.analysis.recording import recorder_short
from fiber_align.config import ConfigError
from fiber_align.control.trajectory import stamp_ns
from fiber_align.graph.ranges import SCENARIO_RANGES
from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.bus import Pub, subscription
from fiber_align.nodes.ros.params import declare, declare_graph_values, declare_row
from fiber_align.nodes.ros.params import node_defaults
from fiber_align.nodes.ros.qos import DIAG_QOS, LATCHED_QOS, sample_pub_qos, sample_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.simulation import scenarios
from fiber_align.simulation.setpoints import setpoint_range, Source

#: the registry's entry of this node: its name and params files
SPEC = NODES['scenario_runner']
SCENARIOS = scenarios.NAMES
#: Accepted as a parameter value; ``none`` starts no runner (graph/description.py, bringup).
CHOICES = ('none',) + SCENARIOS


class ScenarioRunnerNode(Node):
    """Publish a scenario's setpoint (or open-loop drive) for every displacement sample."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare the parameters (defaults from config/) and wire the topics.

        :param bus: the :class:`~fiber_align.nodes.ros.bus.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(SPEC.node, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        self.name_ = declare(self, d, 'scenario', 'scenario to run', read_only=True,
                             choices=SCENARIOS if d.get('scenario') != 'none' else CHOICES)
        if self.name_ == 'none':
            raise ConfigError('scenario_runner: scenario none runs no runner; choose one '
                              'of %s' % ', '.join(SCENARIOS))
        dur = declare_row(self, d, SCENARIO_RANGES, 'duration_s')
        reach = declare_row(self, d, SCENARIO_RANGES, 'reach_m')
        g = declare_graph_values(self, d, 'setpoint_min_m', 'setpoint_max_m', 'sync_mode',
                                 'rate_hz')
        self.exit_when_done = declare(self, d, 'exit_when_done', 'end the process when '
                                      'the scenario is over (ros2 launch)', read_only=True)
        self.wait_recorder = declare(self, d, 'wait_for_recorder', 'at the end, wait for '
                                     'bag_recorder to hold what was sent (bool)',
                                     read_only=True)
        self.recorder_wait_s = declare_row(self, d, SCENARIO_RANGES, 'recorder_wait_s')
        self.lockstep = g['sync_mode'] == 'lockstep'
        self.period_s = 1.0 / g['rate_hz']
        self.source = Source(self.name_, *setpoint_range(g['setpoint_min_m'],
                                                         g['setpoint_max_m'], reach))
        self.sc = self.source.sc
        self.duration_s = float(dur) if dur > 0 else float(self.sc.duration_s)
        pub_qos = sample_pub_qos(self.lockstep)
        if self.sc.open_loop:
            self.pub_ff = Pub(self, Float64, 'feedforward_voltage', pub_qos, bus)
            self.pub_fb = Pub(self, Float64, 'feedback_voltage', pub_qos, bus)
        else:
            self.pub_sp = Pub(self, Float64, 'setpoint', pub_qos, bus)
        self.pub_state = self.create_publisher(String, 'scenario_state', LATCHED_QOS)
        subscription(self, JointState, 'displacement', self._on_disp,
                     sample_qos(self.lockstep), bus)
        self._msg = Float64()
        self._zero = Float64(data=0.0)
        self.t0_ns = None
        self.n = 0
        self.done = False
        self.diag = {}                  # node -> newest /diagnostics values, '_t'
        self._t_done = None
        if self.exit_when_done and self.wait_recorder:
            self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag,
                                     DIAG_QOS)
        self.pub_state.publish(String(data='ready'))
        self.get_logger().info('scenario %s, %g s' % (self.name_, self.duration_s))

    def _on_disp(self, msg):
        if self.done:
            return
        ns = stamp_ns(msg.header.stamp)
        if self.t0_ns is None:
            self.t0_ns = ns
            self.pub_state.publish(String(data='running'))
        t = (ns - self.t0_ns) * 1e-9
        if self.lockstep:
            t = round(t / self.period_s) * self.period_s
        if t >= self.duration_s - 0.5 * self.period_s:
            self.done = True
            self.pub_state.publish(String(data='done'))
            self.get_logger().info('scenario done after %d samples' % self.n)
            if self.exit_when_done and self.wait_recorder:
                self._t_done = time.monotonic()
                self.create_timer(0.05, self._exit_once_recorded)
            elif self.exit_when_done:
                # a short grace for the last messages to reach their readers, then the
                # process (and a launch that waits on it) ends
                self.create_timer(0.5, self._exit)
            return
        v = self.source.value(t)
        if not math.isfinite(v):
            return
        m = self._msg
        m.data = float(v)
        if self.sc.open_loop:
            self.pub_ff.publish(m)
            self.pub_fb.publish(self._zero)
        else:
            self.pub_sp.publish(m)
        self.n += 1

    def _on_diag(self, msg):
        now = time.monotonic()
        for st in msg.status:
            node, values = diag_entry(st, now)
            self.diag[node] = values

    def _exit_once_recorded(self):
        check = recorder_short if self.lockstep else recorder_missing
        left = check(self.diag, self._t_done)
        if left is not None and not left:
            self.get_logger().info('the recorder holds what the graph sent')
            self._exit()
        elif time.monotonic() - self._t_done > self.recorder_wait_s:
            self.get_logger().error('after %g s the recorder does not hold what the graph '
                                    'sent (%s); ending anyway' % (self.recorder_wait_s,
                                                                  left_text(left)))
            self._exit()

    def _exit(self):
        self.get_logger().info('scenario over: shutting the process down')
        self.context.try_shutdown()

    def sent_counts(self):
        """Return published message counts per topic."""
        if self.sc.open_loop:
            return {'feedforward_voltage': self.n, 'feedback_voltage': self.n}
        return {'setpoint': self.n}


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(ScenarioRunnerNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
