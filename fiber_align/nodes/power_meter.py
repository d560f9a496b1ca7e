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
``config/hardware.yaml``, node ``power_meter``): ``resource``, ``visa_backend``,
``wavelength_m`` (m), ``averaging_count``, ``rate_hz`` (Hz), ``timeout_s`` (s),
``reconnect_period_s`` (s), ``diagnostics_period_s`` (s).
"""

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from fiber_align.config import load_params
from fiber_align.hardware import errors as er
from fiber_align.hardware.pm100 import PM100

OK, ERROR, STALE = 0, 2, 3
FLOATS = {  # name: (low, high, description)
    'wavelength_m': (200e-9, 20e-6, 'wavelength correction (m), sent in nm'),
    'rate_hz': (0.1, 1000.0, 'largest reading rate (Hz)'),
    'timeout_s': (0.01, 10.0, 'bound on every query (s); no reply = meter lost'),
    'reconnect_period_s': (0.05, 60.0, 'time between reconnection attempts (s)'),
    'diagnostics_period_s': (0.05, 60.0, 'period of /diagnostics (s)'),
}


class PowerMeterNode(Node):
    """Read a PM100 on a thread and publish the power and the meter's health."""

    def __init__(self, **kwargs):
        """Declare the parameters and start the reading thread (``kwargs``: rclpy Node's)."""
        super().__init__('power_meter', **kwargs)
        d = load_params('hardware.yaml', 'power_meter')
        # graph-wide (/** in fiber_align.yaml), as every node of the graph
        d['diagnostics_period_s'] = load_params('fiber_align.yaml', '/**')[
            'diagnostics_period_s']
        self.declare_parameter('resource', str(d['resource']), ParameterDescriptor(
            description='VISA resource (TCPIP::host::port::SOCKET, ASRL..., USB0::...)',
            read_only=True))
        self.declare_parameter('visa_backend', str(d['visa_backend']), ParameterDescriptor(
            description='pyvisa backend (@py = pyvisa-py)', read_only=True))
        self.declare_parameter('averaging_count', int(d['averaging_count']),
                               ParameterDescriptor(
                                   description='SENS:AVER:COUN (samples of ~3 ms each)',
                                   read_only=True, integer_range=[IntegerRange(
                                       from_value=1, to_value=10000, step=1)]))
        for name, (lo, hi, text) in FLOATS.items():
            self.declare_parameter(name, float(d[name]), ParameterDescriptor(
                description=text, read_only=True, floating_point_range=[
                    FloatingPointRange(from_value=lo, to_value=hi)]))
        g = {n: self.get_parameter(n).value for n in
             ('resource', 'visa_backend', 'averaging_count', *FLOATS)}
        self.p = g
        self.meter = PM100(g['resource'], g['wavelength_m'], g['averaging_count'],
                           g['timeout_s'], g['visa_backend'])
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(Float64, 'optical_power', qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', qos)
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

    def destroy_node(self):
        """Stop the reading thread (bounded) and close the meter."""
        self.stop.set()
        self.thread.join(2.0 + self.p['timeout_s'])
        self.meter.close()
        return super().destroy_node()


def main(args=None):
    """Run the node (demo_nodes_py idiom)."""
    rclpy.init(args=args)
    node = None
    try:
        node = PowerMeterNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
