# SPDX-License-Identifier: Apache-2.0
"""``actuator_driver``: a managed (lifecycle) node around :class:`DriverCore`.

Topics (relative names, SI units):

- sub ``feedforward_voltage`` (std_msgs/Float64, V) and ``feedback_voltage`` (V).
- pub ``drive_voltage`` (std_msgs/Float64, V): ``clamp(ff + fb, v_min, v_max)``,
  slew-limited; published only while the node is active (output is 0 V before).
- srv ``enable`` (std_srvs/SetBool): false ramps the output to the safe voltage (0 V,
  the switch's light-off state) and keeps it there; true resumes.
- lifecycle services (``change_state``, ``get_state``, ...) from rclpy.lifecycle.

Pairing: in ``lockstep`` the i-th feedforward is summed with the i-th feedback and the
command time is ``i / rate_hz`` (the plant's sample time), so the output does not depend
on message timing. In ``realtime`` each feedback message (one per displacement sample)
produces one drive with the latest feedforward, and a wall-clock timer at ``rate_hz``
runs the watchdog: no feedback for ``watchdog_timeout_s`` ramps the output to the safe
voltage at the slew limit and reports ERROR on ``/diagnostics``. After the ramp ends
the node stops publishing until input returns.

``v_max`` is checked at configure time against the field limit of the design model
(``max_field_v_per_m * piezo_thickness_m`` of ``config/actuator.yaml``).
"""

import math
import time

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import Float64
from std_srvs.srv import SetBool

from fiber_align.config import ConfigError, load_params
from fiber_align.control.driver import DriverCore
from fiber_align.nodes import _common as c

NODE_NAME = 'actuator_driver'
AREA_FILES = ('driver.yaml',)
CORE_KEYS = ('v_min', 'v_max', 'slew_rate_v_per_s', 'watchdog_timeout_s', 'safe_voltage_v')
RANGES = {'v_min': (-200.0, 200.0), 'v_max': (-200.0, 200.0),
          'slew_rate_v_per_s': (-1.0, 1e12), 'watchdog_timeout_s': (0.0, 60.0),
          'safe_voltage_v': (-200.0, 200.0)}


def field_limit_v(path='actuator.yaml'):
    """Return the largest drive (V) the design model allows, or ``inf`` if unknown."""
    try:
        a = load_params(path, 'actuator')
        return float(a['max_field_v_per_m']) * float(a['piezo_thickness_m'])
    except (ConfigError, KeyError, TypeError, ValueError):
        return math.inf


class ActuatorDriverNode(LifecycleNode):
    """Lifecycle transport around :class:`DriverCore`."""

    def __init__(self, **kwargs):
        """Declare parameters (defaults from config/); nothing is created until configure."""
        super().__init__(NODE_NAME, **kwargs)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        d = {k: v for k, v in d.items() if k in CORE_KEYS + (
            'rate_hz', 'sync_mode', 'diagnostics_period_s')}
        c.declare(self, d, 'rate_hz', 'control rate (Hz)', 1.0, 20000.0, True)
        c.declare(self, d, 'sync_mode', 'message pairing', read_only=True,
                  choices=c.SYNC_MODES)
        c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)', 0.01, 60.0,
                  True)
        units = {'v_min': 'lowest drive (V)', 'v_max': 'highest drive (V)',
                 'slew_rate_v_per_s': 'slew limit (V/s); <= 0: none',
                 'watchdog_timeout_s': 'silence before the safe ramp (s); 0: off',
                 'safe_voltage_v': 'safe (light-off) drive (V)'}
        for k in CORE_KEYS:
            lo, hi = RANGES[k]
            c.declare(self, d, k, units[k], lo, hi)
        self.add_on_set_parameters_callback(self._on_set)
        self.core = None
        self.pub = None
        self.enabled = True
        self.active = False
        self.n_drive = 0
        self.ff_q = []
        self.fb_q = []
        self.ff_latest = 0.0
        self.i = 0
        self._subs = []
        self._timer = None
        self._srv = None
        self.health = c.Health(self, self.get_parameter('diagnostics_period_s').value)
        self.health.status(c.WARN, 'unconfigured: output 0 V')
        self.field_limit_v = field_limit_v()

    # -- parameters -----------------------------------------------------------------
    def _core_params(self, overrides=None):
        p = {k: self.get_parameter(k).value for k in CORE_KEYS}
        p.update(overrides or {})
        return p

    def _check_core(self, p):
        """Return ``None`` or the reason why ``p`` is not a valid driver set-up."""
        if p['v_max'] > self.field_limit_v:
            return ('v_max %g V exceeds the field limit %g V of the design model'
                    % (p['v_max'], self.field_limit_v))
        try:
            DriverCore.from_params(p)
        except (ConfigError, ValueError) as exc:
            return str(exc)
        return None

    def _on_set(self, params):
        """Accept live updates of the limits when in range and consistent."""
        res = c.check_parameters(params, RANGES)
        if not res.successful:
            return res
        new = {p.name: float(p.value) for p in params if p.name in CORE_KEYS}
        if new:
            why = self._check_core(self._core_params(new))
            if why:
                res.successful = False
                res.reason = why
                return res
            if self.core is not None:
                core = self.core
                core.v_min = new.get('v_min', core.v_min)
                core.v_max = new.get('v_max', core.v_max)
                core.timeout = new.get('watchdog_timeout_s', core.timeout)
                core.safe = new.get('safe_voltage_v', core.safe)
                if 'slew_rate_v_per_s' in new:
                    s = new['slew_rate_v_per_s']
                    core.slew = s if s > 0 and math.isfinite(s) else math.inf
        return res

    # -- lifecycle ------------------------------------------------------------------
    def on_configure(self, state):
        """Build the core and the transport; output stays 0 V (nothing published)."""
        p = self._core_params()
        why = self._check_core(p)
        if why:
            self.get_logger().error('cannot configure: %s' % why)
            self.health.status(c.ERROR, why)
            return TransitionCallbackReturn.FAILURE
        self.core = DriverCore.from_params(p)
        self.period_s = 1.0 / float(self.get_parameter('rate_hz').value)
        self.lockstep = self.get_parameter('sync_mode').value == 'lockstep'
        self.pub = self.create_publisher(Float64, 'drive_voltage', c.CONTROL_QOS)
        self._subs = [
            self.create_subscription(Float64, 'feedforward_voltage', self._on_ff,
                                     c.CONTROL_QOS),
            self.create_subscription(Float64, 'feedback_voltage', self._on_fb,
                                     c.CONTROL_QOS)]
        self._srv = self.create_service(SetBool, '~/enable', self._on_enable)
        if not self.lockstep:
            self._timer = self.create_timer(self.period_s, self._on_tick,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.health.status(c.OK, 'configured (inactive): output 0 V')
        self._update_values()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        """Start publishing drive commands."""
        self.active = True
        self.health.status(c.OK, 'active')
        self.get_logger().info('active: %s pairing, %g..%g V'
                               % ('lockstep' if self.lockstep else 'latest',
                                  self.core.v_min, self.core.v_max))
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Stop publishing; the last published command is followed by the safe voltage."""
        if self.pub is not None and self.core is not None:
            self._publish(self.core.safe)
        self.active = False
        safe = self.core.safe if self.core else 0.0
        self.health.status(c.OK, 'inactive: output %g V' % safe)
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Destroy the transport and the core."""
        self._teardown()
        self.health.status(c.WARN, 'unconfigured: output 0 V')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        """Tear down on shutdown."""
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self):
        for s in self._subs:
            self.destroy_subscription(s)
        self._subs = []
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        if self._srv is not None:
            self.destroy_service(self._srv)
            self._srv = None
        if self.pub is not None:
            self.destroy_publisher(self.pub)
            self.pub = None
        self.core = None
        self.active = False

    # -- control --------------------------------------------------------------------
    def _on_enable(self, request, response):
        """Enable (true) or disable (false: ramp to the safe voltage) the output."""
        self.enabled = bool(request.data)
        response.success = True
        response.message = 'output %s' % ('enabled' if self.enabled else
                                          'disabled: ramping to the safe voltage')
        self.get_logger().info(response.message)
        return response

    def _now(self):
        return time.monotonic()

    def _on_ff(self, msg):
        if self.lockstep:
            self.ff_q.append(msg.data)
            self._pair()
        else:
            self.ff_latest = msg.data

    def _on_fb(self, msg):
        if self.lockstep:
            self.fb_q.append(msg.data)
            self._pair()
            return
        self._command(self.ff_latest, msg.data, self._now())

    def _pair(self):
        while self.ff_q and self.fb_q:
            ff = self.ff_q.pop(0)
            fb = self.fb_q.pop(0)
            t = self.i * self.period_s
            self.i += 1
            self._command(ff, fb, t)

    def _command(self, ff, fb, t):
        core = self.core
        if core is None:
            return
        if self.enabled:
            was_tripped = core.tripped
            v = core.command(ff, fb, t)
            if was_tripped:
                self.health.status(c.OK, 'active')
                self.get_logger().info('input is back: watchdog cleared')
        else:
            v = core._limit(core.safe, t)
        if self.active:
            self._publish(v)

    def _on_tick(self):
        """Realtime watchdog (wall clock)."""
        core = self.core
        if core is None or not self.active:
            return
        t = self._now()
        if not self.enabled:
            if core.v != core.safe or core.t_last_out is None:
                self._publish(core._limit(core.safe, t))
            return
        before = core.watchdog_count
        was_at = core.v
        v = core.tick(t)
        if core.watchdog_count > before:
            msg = ('no feedback_voltage for %.3g s: ramping to %g V'
                   % (core.timeout, core.safe))
            self.get_logger().error(msg)
            self.health.status(c.ERROR, msg)
        if core.tripped and (v != was_at or self._last_pub != v):
            self._publish(v)
        if self.n_drive and self.n_drive % 500 == 0:
            self._update_values()

    _last_pub = None

    def _publish(self, v):
        self.pub.publish(Float64(data=float(v)))
        self._last_pub = float(v)
        self.n_drive += 1

    def _update_values(self):
        core = self.core
        if core is None:
            return
        self.health.set_values(**{
            'drive_v': core.v, 'enabled': self.enabled, 'active': self.active,
            'saturation_count': core.saturation_count, 'slew_count': core.slew_count,
            'watchdog_count': core.watchdog_count, 'nan_count': core.nan_count,
            'sent.drive_voltage': self.n_drive})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'drive_voltage': self.n_drive}


def main(args=None):
    """Run the node (demo_nodes_py idiom)."""
    rclpy.init(args=args)
    node = None
    try:
        node = ActuatorDriverNode()
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
