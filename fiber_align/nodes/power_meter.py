# SPDX-License-Identifier: Apache-2.0
"""
``power_meter``: a Thorlabs PM100 (SCPI through pyvisa) publishing ``optical_power``.

Publishes ``optical_power`` (std_msgs/Float64, W) once per reading, at up to ``rate_hz``
(Hz), and ``/diagnostics`` every ``diagnostics_period_s`` (s) and at once on a change of
level: OK while readings flow, with the achieved rate (Hz), the stamp of the last
reading (s, this node's clock), the reading count and the meter's ``SYST:ERR?`` queue;
ERROR with the reason (``PM100: no reply within timeout: ...``) when the meter is lost.
A lost meter is reopened every ``reconnect_period_s`` (s) and the node keeps running.

The meter is read on a thread of its own (:class:`fiber_align.hardware.pm100_session.
MeterReader`); rclpy publishers are thread-safe. Parameters (read-only, defaults from
``config/hardware.yaml``, node ``power_meter``; ``resource`` from its ``/**`` section, where
a command line's ``-p resource:=...`` wins): ``resource``, ``visa_backend``,
``wavelength_m`` (m), ``averaging_count``, ``rate_hz`` (Hz), ``timeout_s`` (s),
``reconnect_period_s`` (s), ``diagnostics_period_s`` (s).
"""

import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from std_msgs.msg import Float64

from fiber_align.config import load_params
from fiber_align.graph.ranges import POWER_METER_RANGES
from fiber_align.hardware.pm100 import PM100
from fiber_align.hardware.pm100_session import MeterReader
from fiber_align.nodes.ros.diagnostics import ERROR
from fiber_align.nodes.ros.params import declare
from fiber_align.nodes.ros.qos import DIAG_QOS
from fiber_align.nodes.ros.runtime import run_node

#: name: (description, low, high); all read-only (the graph checks the same table)
PARAMS = POWER_METER_RANGES


class PowerMeterNode(Node):
    """Publish the power a :class:`~fiber_align.hardware.pm100_session.MeterReader` reads."""

    def __init__(self, **kwargs):
        """Declare the parameters and start the reading thread (``kwargs``: rclpy Node's)."""
        super().__init__('power_meter', **kwargs)
        d = load_params('hardware.yaml', 'power_meter')
        # the device address sits under /** so that a command line's -p wins over it
        d['resource'] = load_params('hardware.yaml', '/**')['resource']
        # graph-wide (/** in fiber_align.yaml), as every node of the graph
        d['diagnostics_period_s'] = load_params('fiber_align.yaml', '/**')[
            'diagnostics_period_s']
        g = {name: declare(self, d, name, text, lo, hi, True)
             for name, (text, lo, hi) in PARAMS.items()}
        self.p = g
        self.pub = self.create_publisher(Float64, 'optical_power', DIAG_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', DIAG_QOS)
        self.reader = MeterReader(
            PM100(g['resource'], g['wavelength_m'], g['averaging_count'], g['timeout_s'],
                  g['visa_backend']), g['rate_hz'], g['diagnostics_period_s'],
            g['reconnect_period_s'], self.publish_power, self.on_health)
        self.timer = self.create_timer(g['diagnostics_period_s'], self.publish_diagnostics)
        self.reader.start()

    def on_health(self, level, message):
        """Log a change of the meter's health; publish /diagnostics at once."""
        # two call sites: rclpy's logger refuses a second severity from one
        if level == ERROR:
            self.get_logger().error(message)
        else:
            self.get_logger().info(message)
        self.publish_diagnostics()

    def _publish(self, pub, msg):
        """Publish unless the context is gone (SIGINT); then stop the reading thread."""
        if self.reader.stop.is_set() or not self.context.ok():
            self.reader.stop.set()
            return False
        try:
            pub.publish(msg)
        except Exception:  # noqa: BLE001 - the context shut down under the thread
            if self.context.ok():
                raise
            self.reader.stop.set()
            return False
        return True

    def publish_power(self, p_w):
        """Publish one reading (W); return its stamp (s, node clock), ``None`` at the stop."""
        if self._publish(self.pub, Float64(data=float(p_w))):
            return self.get_clock().now().nanoseconds * 1e-9
        return None

    def publish_diagnostics(self):
        """Publish the meter's status on /diagnostics."""
        level, message, values = self.reader.status()
        st = DiagnosticStatus(level=bytes([level]), name=self.get_fully_qualified_name(),
                              message=message, hardware_id=self.p['resource'])
        values.update(wavelength_m='%g' % self.p['wavelength_m'],
                      averaging_count=str(self.p['averaging_count']))
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._publish(self.diag_pub, msg)

    def close(self):
        """Stop the reading thread (bounded) and close the meter (idempotent)."""
        if getattr(self, '_closed', False):
            return
        self._closed = True
        self.reader.close(2.0 + self.p['timeout_s'])

    def destroy_node(self):
        """Close the meter (:meth:`close`), then destroy the node."""
        self.close()
        return super().destroy_node()


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(PowerMeterNode, 'power_meter', args, realtime=lambda node: False)


if __name__ == '__main__':
    sys.exit(main())
