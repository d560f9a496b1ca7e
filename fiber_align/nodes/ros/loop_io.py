# SPDX-License-Identifier: Apache-2.0
"""
What ``hysteresis_compensator`` and ``fuzzy_pid_controller`` share around their step.

:class:`LoopIO` is composed into each of the two nodes and owns its part (as
control_toolbox's ``PidROS`` owns a ``Pid``): the graph-wide values both read
(read-only), the reference shaping and its design model, the accepted setpoint
(:class:`fiber_align.control.trajectory.Setpoint`, m), the node's ``/diagnostics``
(:class:`~fiber_align.nodes.ros.diagnostics.Health`) with the realtime cycle statistics
(sample-to-output latency, s), and in realtime the driver's ``drive_held``
(std_msgs/Bool, latched) and ``drive_voltage`` (std_msgs/Float64, V), handed to the
node's step (:mod:`fiber_align.control.realtime`). SI units.
"""

import time

from std_msgs.msg import Bool, Float64

from fiber_align.control.cycle import CycleStats
from fiber_align.control.trajectory import Setpoint
from fiber_align.nodes.ros.bus import sender_of, slack_of, subscription
from fiber_align.nodes.ros.diagnostics import Health
from fiber_align.nodes.ros.params import declare_graph_values, declare_shaping, design_model
from fiber_align.nodes.ros.params import PRIORITY
from fiber_align.nodes.ros.qos import LATCHED_QOS, REALTIME_QOS

#: The graph-wide values both nodes read (read-only).
GRAPH = ('controller', 'rate_hz', 'sync_mode', 'diagnostics_period_s', 'setpoint_min_m',
         'setpoint_max_m', 'realtime_setpoint_rate_m_per_s',
         'realtime_setpoint_accel_m_per_s2') + PRIORITY


class LoopIO:
    """The ROS side of a control-loop node's step (see the module docstring)."""

    def __init__(self, node, defaults, bus, *extra):
        """
        Declare the graph-wide values (:data:`GRAPH` and ``extra``) and the shaping.

        :param node: the node it serves.
        :param defaults: the node's defaults (``node_defaults``).
        :param bus: the process's :class:`~fiber_align.nodes.ros.bus.LocalBus` or None.
        """
        self.node, self.bus = node, bus
        self.g = declare_graph_values(node, defaults, *(GRAPH + extra))
        self.rate_hz = self.g['rate_hz']
        self.period_s = 1.0 / self.rate_hz
        self.lockstep = self.g['sync_mode'] == 'lockstep'
        self.sp = Setpoint(self.g['setpoint_min_m'], self.g['setpoint_max_m'])
        self.shaping = declare_shaping(node, defaults)   # the reference model's (SHARED)
        self.design = design_model(self.shaping)    # (omega_n rad/s, gain m/V)
        self.slack = slack_of(bus)
        self.health = None

    def step_args(self):
        """Return ``(period_s, rate_m_per_s, accel_m_per_s2)`` of the realtime step."""
        return (self.period_s, self.g['realtime_setpoint_rate_m_per_s'],
                self.g['realtime_setpoint_accel_m_per_s2'])

    def watch_driver(self, held, drive):
        """
        Realtime: subscribe ``drive_held`` and ``drive_voltage`` of the driver.

        :param held: called with True (the driver holds its output) or False.
        :param drive: called when a drive command arrived (the loop is closed).
        """
        subscription(self.node, Bool, 'drive_held', lambda msg: held(bool(msg.data)),
                     LATCHED_QOS, self.bus)
        subscription(self.node, Float64, 'drive_voltage', lambda msg: drive(), REALTIME_QOS,
                     self.bus)

    def serve_health(self, cycle):
        """Create the node's ``/diagnostics``; ``cycle``: with the cycle statistics."""
        self.health = Health(self.node, self.g['diagnostics_period_s'], slack=self.slack,
                             sender=sender_of(self.bus))
        if cycle:
            self.health.cycle = CycleStats(self.rate_hz)
        return self.health

    def take(self, value):
        """Take a setpoint (m); return ``None`` or why it was refused (logged, a WARN)."""
        why = self.sp.take(value)
        if why:
            self.node.get_logger().warn(why)
            self.health.warn(why)
        return why

    def latency(self, ns):
        """Record the time (s) from the sample stamped ``ns`` (ns) to now, if counted."""
        cyc = self.health.cycle
        if cyc is not None:
            cyc.record((time.time_ns() - ns) * 1e-9, cyc.index(ns))

    def report(self, **values):
        """Put ``values``, the refused setpoints and the held setpoint (m) on diagnostics."""
        self.health.set_values(rejected_setpoints=self.sp.rejected, setpoint_m=self.sp.value,
                               **values)
