# SPDX-License-Identifier: Apache-2.0
"""``hysteresis_compensator``: the feedforward (inverse PI model) as a ROS 2 node.

One ``feedforward_voltage`` (std_msgs/Float64, V) per ``setpoint`` (std_msgs/Float64, m):
``ff = Feedforward.step(r)`` of :mod:`fiber_align.control.feedforward`, the exact inverse
of the Prandtl-Ishlinskii model, after the optional resonance-suppression shaper
(``shaping``: none | zv | zvd, :mod:`fiber_align.control.shaping`), built by
:func:`fiber_align.control.simulate.build` for the graph's ``controller`` so that it is
exactly the offline loop's feedforward (``fuzzy``/``pid``: 0 V; ``open-loop``: linear).

Parameters: the model (``thresholds_v``, ``weights_m_per_v``) inline or in
``model_file`` (a params file written by ``PIModel.save``), the shaping, and
``controller`` (graph-wide, see above). Service ``reload_model`` (std_srvs/Trigger)
reads the model again (e.g. after ``fiber-align identify`` wrote a new file); it keeps the
old model when the new one cannot be loaded or inverted.

A NaN, infinite or out-of-range setpoint is rejected with a logged reason and a WARN on
``/diagnostics``; the last valid setpoint is used in its place, so exactly one output is
published per input (lockstep pairing holds) and the actuator stays where it was.
"""

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from fiber_align.config import ConfigError
from fiber_align.control.simulate import build
from fiber_align.hysteresis.pi import PIModel
from fiber_align.nodes import _common as c

NODE_NAME = 'hysteresis_compensator'
AREA_FILES = ('compensator.yaml',)
CONTROLLERS = ('composite', 'composite-pid', 'fuzzy', 'pid', 'feedforward', 'open-loop')
SHAPING = ('none', 'zv', 'zvd')


class HysteresisCompensatorNode(Node):
    """Transport, parameters and the reload service around :class:`Feedforward`."""

    def __init__(self, **kwargs):
        """Declare parameters (defaults from config/), load the model, wire topics."""
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        self.rate_hz = c.declare(self, d, 'rate_hz', 'control rate (Hz)', 1.0, 20000.0, True)
        self.lockstep = c.declare(self, d, 'sync_mode', 'sample clock', read_only=True,
                                  choices=c.SYNC_MODES) == 'lockstep'
        diag = c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)', 0.01,
                         60.0, True)
        self.sp_lo = c.declare(self, d, 'setpoint_min_m', 'lowest accepted setpoint (m)',
                               -1e-3, 1e-3, True)
        self.sp_hi = c.declare(self, d, 'setpoint_max_m', 'highest accepted setpoint (m)',
                               -1e-3, 1e-3, True)
        c.declare(self, d, 'controller', 'control law (as in fiber-align simulate)',
                  read_only=True, choices=CONTROLLERS)
        self.comp_defaults = {k: v for k, v in d.items()}
        c.declare(self, d, 'model_file', 'PI model params file; empty: the inline model')
        c.declare(self, d, 'model_source', 'where the inline model comes from')
        c.declare(self, d, 'thresholds_v', 'PI play-operator thresholds (V)')
        c.declare(self, d, 'weights_m_per_v', 'PI weights (m/V)')
        c.declare(self, d, 'shaping', 'resonance suppression of the reference',
                  read_only=True, choices=SHAPING)
        c.declare(self, d, 'shaping_omega_n_rad_s', 'mode to suppress (rad/s); <= 0: design',
                  -1.0, 1e6, True)
        c.declare(self, d, 'shaping_damping_ratio', 'damping ratio of that mode (1)', 0.0,
                  0.999, True)
        c.declare(self, d, 'open_loop_gain_v_per_m', 'linear feedforward gain (V/m)', 0.0,
                  1e9, True)
        self.pub = self.create_publisher(Float64, 'feedforward_voltage', c.CONTROL_QOS)
        self.create_subscription(Float64, 'setpoint', self._on_setpoint, c.CONTROL_QOS)
        self.create_service(Trigger, '~/reload_model', self._on_reload)
        self.health = c.Health(self, diag)
        self.r = 0.0
        self.n_ff = 0
        self.rejected = 0
        self.ff = self.build()
        self.health.status(c.OK, 'ready (%s)' % self.get_parameter('controller').value)
        self.get_logger().info('compensator ready: %s, shaping %s, model %s'
                               % (self.get_parameter('controller').value,
                                  self.get_parameter('shaping').value, self.model_name()))

    def model_name(self):
        """Return where the model comes from (file path or ``inline``)."""
        return self.get_parameter('model_file').value or 'inline'

    def load_model(self):
        """Return the PI model of the parameters (or of ``model_file``)."""
        path = self.get_parameter('model_file').value
        if path:
            return PIModel.load(path)
        return PIModel([float(x) for x in self.get_parameter('thresholds_v').value],
                       [float(x) for x in self.get_parameter('weights_m_per_v').value])

    def build(self):
        """Return a fresh :class:`Feedforward` (V from m) for the parameters."""
        comp = dict(self.comp_defaults)
        comp.update({k: self.get_parameter(k).value for k in
                     ('shaping', 'shaping_omega_n_rad_s', 'shaping_damping_ratio',
                      'open_loop_gain_v_per_m')})
        return build(self.get_parameter('controller').value, self.rate_hz, None,
                     model=self.load_model(), comp_params=comp)[0]

    def _on_reload(self, request, response):
        """Reload the model; keep the old one if the new one fails."""
        try:
            ff = self.build()
        except (ConfigError, ValueError, OSError, KeyError) as exc:
            response.success = False
            response.message = 'kept the old model: %s' % exc
            self.get_logger().error(response.message)
            self.health.warn(response.message)
            return response
        ff.step(self.r)   # start the new inverse at the present setpoint
        self.ff = ff
        response.success = True
        response.message = 'model reloaded from %s' % self.model_name()
        self.get_logger().info(response.message)
        return response

    def _on_setpoint(self, msg):
        why = c.check_setpoint(msg.data, self.sp_lo, self.sp_hi)
        if why is None:
            self.r = float(msg.data)
        else:
            self.rejected += 1
            text = 'rejected %s; holding %.6g m' % (why, self.r)
            self.get_logger().warn(text)
            self.health.warn(text)
        self.pub.publish(Float64(data=float(self.ff.step(self.r))))
        self.n_ff += 1
        if self.n_ff % 500 == 0 or why is not None:
            self.health.set_values(**{'sent.feedforward_voltage': self.n_ff,
                                      'rejected_setpoints': self.rejected,
                                      'setpoint_m': self.r})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'feedforward_voltage': self.n_ff}


def main(args=None):
    """Run the node (demo_nodes_py idiom)."""
    rclpy.init(args=args)
    node = None
    try:
        node = HysteresisCompensatorNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            c.report_sent(node, node.sent_counts())
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
