# SPDX-License-Identifier: Apache-2.0
"""
``power_meter``: a Thorlabs PM100 (SCPI through pyvisa) publishing ``optical_power``.

Publishes ``optical_power`` (std_msgs/Float64, W) once per reading, at up to ``rate_hz``
(Hz), and ``/diagnostics`` every ``diagnostics_period_s`` (s) and at once on a change of
level: OK while readings flow, with the achieved rate (Hz), the stamp of the last
reading (s, this node's clock), the reading count and the meter's ``SYST:ERR?`` queue;
ERROR with the reason (``PM100: no reply within timeout: ...``) when the meter is lost.
A lost meter is reopened every ``reconnect_period_s`` (s) and the node keeps running.

The meter is read on a thread of its own (pyvisa calls block for about 3 ms per averaged
sample); rclpy publishers are thread-safe. Parameters (read-only, defaults from
``config/hardware.yaml``, node ``power_meter``; ``resource`` from its ``/**`` section, where
a command line's ``-p resource:=...`` wins): ``resource``, ``visa_backend``,
``wavelength_m`` (m), ``averaging_count``, ``rate_hz`` (Hz), ``timeout_s`` (s),
``reconnect_period_s`` (s), ``diagnostics_period_s`` (s).
"""

import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from std_msgs.msg import Float64

from fiber_align.config import load_params
from fiber_align.graph.ranges import POWER_METER_RANGES
from fiber_align.hardware import errors as er
from fiber_align.hardware.pm100 import PM100
from fiber_align.nodes.ros.diagnostics import ERROR, OK, STALE
from fiber_align.nodes.ros.params import declare
from fiber_align.nodes.ros.qos import DIAG_QOS
from fiber_align.nodes.ros.runtime import run_node

#: name: (description, low, high); all read-only (the graph checks the same table)
PARAMS = POWER_METER_RANGES


class PowerMeterNode(Node):
    """Read a PM100 on a thread and publish the power and the meter's health."""

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
        self.meter = PM100(g['resource'], g['wavelength_m'], g['averaging_count'],
                           g['timeout_s'], g['visa_backend'])
        self.pub = self.create_publisher(Float64, 'optical_power', DIAG_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', DIAG_QOS)
        self.lock = threading.Lock()
        self.level, self.message = STALE, 'connecting to the meter'
        self.readings = 0
        self.last_stamp = None
        self.times = []
        self.meter_errors = []
        self.published = 0
        self.stop = threading.Event()
        self.timer = self.create_timer(g['diagnostics_period_s'], self.publish_diagnostics)
        self.thread = threading.Thread(target=self.loop, name='power_meter', daemon=True)
        self.thread.start()

    def set_health(self, level, message):
        """Record the health; publish /diagnostics at once when the level changes."""
        with self.lock:
            changed = level != self.level
            self.level, self.message = level, message
        if changed and not self.stop.is_set():
            if level == ERROR:
                self.get_logger().error(message)
            else:
                self.get_logger().info(message)
            self.publish_diagnostics()

    def loop(self):
        """Connect, read at ``rate_hz``, reconnect after a loss; until :attr:`stop`."""
        period = 1.0 / self.p['rate_hz']
        while not self.stop.is_set():
            try:
                self.meter.open()
                self.meter.configure()
                self.set_health(OK, 'reading %s (%s)'
                                % (self.p['resource'], self.meter.ident))
                t_next = time.monotonic()
                t_err = t_next
                while not self.stop.is_set():
                    p = self.meter.read_w()
                    self.publish_power(p)
                    now = time.monotonic()
                    if now - t_err >= self.p['diagnostics_period_s']:
                        t_err = now
                        errs = self.meter.errors()
                        if errs:
                            with self.lock:
                                self.meter_errors = (self.meter_errors + errs)[-10:]
                    t_next += period
                    delay = t_next - time.monotonic()
                    if delay > 0:
                        self.stop.wait(delay)
                    else:
                        t_next = time.monotonic()
            except er.DeviceError as exc:
                self.meter.close()
                self.set_health(ERROR, str(exc))
                self.stop.wait(self.p['reconnect_period_s'])
        self.meter.close()

    def _publish(self, pub, msg):
        """Publish unless the context is gone (SIGINT); then stop the reading thread."""
        if self.stop.is_set() or not self.context.ok():
            self.stop.set()
            return False
        try:
            pub.publish(msg)
        except Exception:  # noqa: BLE001 - the context shut down under the thread
            if self.context.ok():
                raise
            self.stop.set()
            return False
        return True

    def publish_power(self, p_w):
        """Publish one reading (W) and note its stamp (s, node clock)."""
        if not self._publish(self.pub, Float64(data=float(p_w))):
            return
        t = self.get_clock().now().nanoseconds * 1e-9
        with self.lock:
            self.published += 1
            self.readings += 1
            self.last_stamp = t
            self.times.append(time.monotonic())
            del self.times[:-200]

    def achieved_rate_hz(self):
        """Return the reading rate (Hz) over the last second (0 when none)."""
        with self.lock:
            now = time.monotonic()
            recent = [t for t in self.times if now - t <= 1.0]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / (recent[-1] - recent[0])

    def publish_diagnostics(self):
        """Publish the meter's status on /diagnostics."""
        rate = self.achieved_rate_hz()
        with self.lock:
            st = DiagnosticStatus(level=bytes([self.level]), name=self.get_fully_qualified_name(),
                                  message=self.message, hardware_id=self.p['resource'])
            values = {'rate_hz': '%.2f' % rate, 'readings': str(self.readings),
                      'last_stamp_s': '' if self.last_stamp is None else
                      '%.6f' % self.last_stamp,
                      'meter_errors': '; '.join('%d %s' % e for e in self.meter_errors),
                      'wavelength_m': '%g' % self.p['wavelength_m'],
                      'averaging_count': str(self.p['averaging_count'])}
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._publish(self.diag_pub, msg)

    def close(self):
        """Stop the reading thread (bounded) and close the meter (idempotent)."""
        if getattr(self, '_closed', False):
            return
        self._closed = True
        self.stop.set()
        self.thread.join(2.0 + self.p['timeout_s'])
        self.meter.close()

    def destroy_node(self):
        """Close the meter (:meth:`close`), then destroy the node."""
        self.close()
        return super().destroy_node()


def main(args=None):
    """Run the node (bad parameters: one line, exit 2)."""
    return run_node(PowerMeterNode, 'power_meter', args, realtime=lambda node: False)


if __name__ == '__main__':
    sys.exit(main())
