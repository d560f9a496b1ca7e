# SPDX-License-Identifier: Apache-2.0
"""
``actuator_driver``: a managed (lifecycle) node around :class:`DriverCore`.

Sums ``feedforward_voltage`` and ``feedback_voltage`` (std_msgs/Float64, V), clamps and
slew-limits them and publishes ``drive_voltage`` (V) while active; ``~/enable``
(std_srvs/SetBool) false ramps to the safe voltage and holds it. Lockstep pairs the i-th
feedforward with the i-th feedback; realtime takes the newest of each. The realtime
watchdog (1 ms ticks) ramps to ``safe_voltage_v`` at ``safe_ramp_rate_v_per_s`` when the
input stops for ``watchdog_timeout_s``, holds until the input has been fresh for
:data:`RECOVERY_S`, and latches after ``latch_trips`` trips within ``latch_window_s``
(until ``~/enable`` true or a lifecycle deactivate/activate). ``drive_held`` (latched
Bool) tells the compensator and the controller to park at the measured position, so a
resume is bumpless. ``v_min``, ``v_max`` and ``safe_voltage_v`` are checked against both
field limits of the PZT layers (``fiber_align.control.driver.check_field_limits``); a
``change_state`` the present state does not offer is refused, not fatal
(``_runtime.guard_change_state``). The full behaviour, with the reasons:
docs/ros_interface.md, section "actuator_driver".
"""

import math
import sys
import time

from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool

from fiber_align.config import ConfigError
from fiber_align.control.driver import check_field_limits, DriverCore
from fiber_align.nodes import _common as c

NODE_NAME = 'actuator_driver'
#: Topics this node publishes (relative names; see ``_common.LocalBus``).
PUBLISHES = ('drive_voltage', 'drive_held')
AREA_FILES = ('driver.yaml',)
#: Uninterrupted fresh input (s, wall) the driver waits for before it ends a trip.
RECOVERY_S = 0.02
CORE_KEYS = ('v_min', 'v_max', 'slew_rate_v_per_s', 'watchdog_timeout_s', 'safe_voltage_v',
             'latch_trips', 'latch_window_s', 'safe_ramp_rate_v_per_s')
LIMIT_KEYS = ('field_limit_v', 'coercive_field_v', 'depoling_fraction')
RANGES = {'v_min': (-1000.0, 1000.0), 'v_max': (-1000.0, 1000.0),
          'slew_rate_v_per_s': (-1.0, 1e12), 'watchdog_timeout_s': (0.0, 60.0),
          'safe_voltage_v': (-1000.0, 1000.0), 'latch_trips': (0, 1000),
          'latch_window_s': (0.0, 3600.0), 'safe_ramp_rate_v_per_s': (-1.0, 1e12)}
UNITS = {'v_min': 'lowest drive (V)', 'v_max': 'highest drive (V)',
         'slew_rate_v_per_s': 'slew limit (V/s); <= 0: none',
         'watchdog_timeout_s': 'silence before the safe ramp (s); 0: off',
         'safe_voltage_v': 'safe (light-off) drive (V)',
         'latch_trips': 'watchdog trips within latch_window_s that latch the safe '
                        'voltage (0: never)',
         'latch_window_s': 'window of the latch count (s)',
         'safe_ramp_rate_v_per_s': 'rate of every ramp to the safe voltage (V/s); <= 0: '
                                   'the slew limit'}


class ActuatorDriverNode(LifecycleNode):
    """Lifecycle transport around :class:`DriverCore`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare parameters (defaults from config/); nothing is created until configure.

        :param bus: the :class:`~fiber_align.nodes._common.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(NODE_NAME, **kwargs)
        self.bus = bus
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        d = {k: v for k, v in d.items() if k in CORE_KEYS + LIMIT_KEYS + (
            'rate_hz', 'sync_mode', 'diagnostics_period_s', 'realtime_priority')}
        c.declare(self, d, 'rate_hz', 'control rate (Hz)', 1.0, 20000.0, True)
        c.declare(self, d, 'sync_mode', 'message pairing', read_only=True,
                  choices=c.SYNC_MODES)
        c.declare(self, d, 'diagnostics_period_s', '/diagnostics period (s)', 0.01, 60.0,
                  True)
        c.declare(self, d, 'field_limit_v', 'forward field limit of the PZT layers (V)',
                  0.0, 1000.0, True)
        c.declare(self, d, 'coercive_field_v', 'coercive field times layer thickness (V)',
                  0.0, 10000.0, True)
        c.declare(self, d, 'depoling_fraction', 'reverse drive allowed, as a fraction of '
                  'coercive_field_v (1)', 0.0, 1.0, True)
        c.declare_priority(self, d)
        for k in CORE_KEYS:
            lo, hi = RANGES[k]
            c.declare(self, d, k, UNITS[k], lo, hi)
        why = check_field_limits(self._core_params())
        if why:
            raise ConfigError('actuator_driver: %s' % why)
        self.add_on_set_parameters_callback(self._on_set)
        self.core = None
        self.pub = None
        self.enabled = True
        self.active = False
        self.n_drive = 0
        self.ff_q = []
        self.fb_q = []
        self._msg = Float64()
        self.ff_latest = 0.0
        self.t_ff = None                # realtime: wall time (s) of the latest feedforward
        self.i = 0
        self._subs = []
        self._timer = None
        self._srv = None
        self._t_fresh = None            # realtime: start (s) of fresh input after a trip
        self._t_fresh_last = 0.0
        self.held = None                # last value published on drive_held
        self.pub_held = c.Pub(self, Bool, 'drive_held', c.LATCHED_QOS, bus, latched=True)
        self._set_held(True, 'unconfigured')
        self.health = c.Health(self, self.get_parameter('diagnostics_period_s').value)
        self.health.status(c.WARN, 'unconfigured: output 0 V')
        self.refused_transitions = 0
        c.guard_change_state(self)

    # -- parameters -----------------------------------------------------------------
    def _core_params(self, overrides=None):
        p = {k: self.get_parameter(k).value for k in CORE_KEYS + LIMIT_KEYS}
        p.update(overrides or {})
        return p

    def _check_core(self, p):
        """Return ``None`` or the reason why ``p`` is not a valid driver set-up."""
        why = check_field_limits(p)
        if why:
            return why
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
        if 'latch_trips' in new:
            new['latch_trips'] = int(new['latch_trips'])
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
                core.latch_trips = new.get('latch_trips', core.latch_trips)
                core.latch_window_s = new.get('latch_window_s', core.latch_window_s)
                if 'safe_ramp_rate_v_per_s' in new:
                    r = new['safe_ramp_rate_v_per_s']
                    core.safe_rate = r if r > 0 and math.isfinite(r) else math.inf
                if 'slew_rate_v_per_s' in new:
                    s = new['slew_rate_v_per_s']
                    core.slew = s if s > 0 and math.isfinite(s) else math.inf
        return res

    # -- lifecycle service guard ----------------------------------------------------
    refused_transitions = 0

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
        self.pub = c.Pub(self, Float64, 'drive_voltage', c.CONTROL_QOS, self.bus)
        qos = c.sample_qos(self.lockstep)
        self._subs = [
            c.subscription(self, Float64, 'feedforward_voltage', self._on_ff, qos, self.bus),
            c.subscription(self, Float64, 'feedback_voltage', self._on_fb, qos, self.bus)]
        self._srv = self.create_service(SetBool, '~/enable', self._on_enable)
        if not self.lockstep:
            self._timer = self.create_timer(self.watchdog_period_s(), self._on_tick,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.health.status(c.OK, 'configured (inactive): output 0 V')
        self._update_values()
        return TransitionCallbackReturn.SUCCESS

    def watchdog_period_s(self):
        """
        Return the realtime watchdog timer period (s): one control period.

        Every ramp to the safe voltage advances at this period, in steps of
        ``safe_ramp_rate_v_per_s`` times it (2 mV per us: 2 V), small enough not to ring
        the bending mode.
        """
        return self.period_s

    def on_activate(self, state):
        """Start publishing drive commands (a lifecycle cycle re-arms a latched watchdog)."""
        if self.core.latched:
            self.core.rearm()
            self.get_logger().info('watchdog latch re-armed by activate')
        self.active = True
        self._set_held(not self.enabled or self.core.tripped, 'activated')
        self.health.status(c.OK, 'active')
        self.get_logger().info('active: %s pairing, %g..%g V'
                               % ('lockstep' if self.lockstep else 'latest',
                                  self.core.v_min, self.core.v_max))
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Stop following ff + fb; ramp to the safe voltage (realtime) and hold it there."""
        if self.pub is not None and self.core is not None and self.lockstep:
            self._publish(self.core.safe)
        elif self.core is not None:
            self.core.start_safe_ramp(self._now())
        self.active = False
        self._set_held(True, 'deactivated')
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
            c.unsubscribe(self, s)
        self._subs = []
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        if self._srv is not None:
            self.destroy_service(self._srv)
            self._srv = None
        if self.pub is not None:
            self.pub.destroy(self)
            self.pub = None
        self.core = None
        self.active = False
        self._set_held(True, 'unconfigured')

    # -- control --------------------------------------------------------------------
    def _on_enable(self, request, response):
        """Enable (true) or disable (false: ramp to the safe voltage) the output."""
        if self.enabled and not request.data and self.core is not None:
            self.core.start_safe_ramp(self._now())
        self.enabled = bool(request.data)
        if self.enabled and self.core is not None and self.core.latched:
            self.core.rearm()
            self.get_logger().info('watchdog latch re-armed by ~/enable')
            self.health.status(c.OK, 'active' if self.active else 'inactive')
        self._set_held(not self.enabled or not self.active or (
            self.core is not None and self.core.tripped), 'enable %s' % self.enabled)
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
            self.t_ff = self._now()

    def _on_fb(self, msg):
        if self.lockstep:
            self.fb_q.append(msg.data)
            self._pair()
            return
        now = self._now()
        core = self.core
        if core is not None and core.timeout > 0 and (
                self.t_ff is None or now - self.t_ff > core.timeout):
            return      # stale feedforward: leave it to the watchdog (docstring)
        if core is not None and core.latched:
            return      # latched: only ~/enable or a lifecycle cycle ends it
        if core is not None and core.tripped and self.enabled and not self._recovered(now):
            return      # hold until the input has been fresh for RECOVERY_S (docstring)
        self._command(self.ff_latest, msg.data, now)

    def _recovered(self, now):
        """Return True once fresh input has flowed for ``RECOVERY_S`` after a trip."""
        if self._t_fresh is None or now - self._t_fresh_last > 5.0 * self.period_s:
            if self._t_fresh is None:
                self.get_logger().info('input is back: holding %g s before resuming'
                                       % RECOVERY_S)
            self._t_fresh = now
        self._t_fresh_last = now
        if now - self._t_fresh < RECOVERY_S:
            return False
        self._t_fresh = None
        return True

    def _set_held(self, held, reason):
        """Publish ``drive_held`` (bool) when it changes; ``reason`` goes to the log."""
        held = bool(held)
        if held == self.held:
            return
        self.held = held
        self.pub_held.publish(Bool(data=held))
        self.get_logger().info('drive_held %s (%s)' % (str(held).lower(), reason))

    def _pair(self):
        while self.ff_q and self.fb_q:
            ff = self.ff_q.pop(0)
            fb = self.fb_q.pop(0)
            t = self.i * self.period_s
            self.i += 1
            self._command(ff, fb, t)

    def _command(self, ff, fb, t):
        core = self.core
        if core is None or not self.active:
            return      # inactive: the output ramps to, and stays at, the safe voltage
        if self.enabled:
            was_tripped = core.tripped
            v = core.command(ff, fb, t)
            if was_tripped:
                msg = 'input is back: watchdog cleared after trip %d' % core.watchdog_count
                self._set_held(not self.active, 'input is back')
                self.health.status(c.OK, 'active')
                self.health.set_values(watchdog_count=core.watchdog_count)
                self.get_logger().info(msg)
        else:
            v = core._limit(core.safe, t)
        if self.active:
            self._publish(v)

    def _on_tick(self):
        """Realtime watchdog (wall clock)."""
        core = self.core
        if core is None:
            return
        t = self._now()
        if not self.active or not self.enabled:
            # inactive or disabled: ramp to the safe voltage, then publish no more
            if core.v != core.safe or (self.active and core.t_last_out is None):
                self._publish(core.ramp_safe(t))
            return
        before = core.watchdog_count
        was_at = core.v
        v = core.tick(t)
        if core.watchdog_count > before:
            msg = ('watchdog: no fresh feedback_voltage and feedforward_voltage for %.3g s: '
                   'ramping to %g V' % (core.timeout, core.safe))
            self.get_logger().error(msg)
            self.health.status(c.ERROR, msg)
            self.health.set_values(watchdog_count=core.watchdog_count)
            self.health.error(msg)
            self._set_held(True, 'watchdog')
            self._t_fresh = None
            if core.latched:
                msg = ('watchdog latched after %d trips within %g s: output held at %g V '
                       'until ~/enable true or a lifecycle deactivate/activate'
                       % (len(core.trip_times), core.latch_window_s, core.safe))
                self.get_logger().error(msg)
                self.health.status(c.ERROR, msg)
                self.health.error(msg)
        if core.tripped and (v != was_at or self._last_pub != v):
            self._publish(v)
        self._ticks += 1
        if self._ticks % 20 == 0:
            self._update_values()

    _ticks = 0

    _last_pub = None

    def _publish(self, v):
        msg = self._msg
        msg.data = float(v)
        self.pub.publish(msg)
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
            'watchdog_latched': core.latched,
            'sent.drive_voltage': self.n_drive})

    def sent_counts(self):
        """Return published message counts per topic."""
        return {'drive_voltage': self.n_drive}


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    stop = c.init(args)
    node = None
    try:
        node = ActuatorDriverNode()
        c.spin(node, realtime=node.get_parameter('sync_mode').value == 'realtime',
               priority=c.node_priority(node), stop=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except c.NODE_ERRORS as exc:
        return c.refuse(NODE_NAME, exc)
    finally:
        c.finish(node)
    return 0


if __name__ == '__main__':
    sys.exit(main())
