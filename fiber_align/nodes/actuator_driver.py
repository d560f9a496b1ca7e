# SPDX-License-Identifier: Apache-2.0
"""
``actuator_driver``: a managed (lifecycle) node around :class:`DriverCore`.

Topics (relative names, SI units):

- sub ``feedforward_voltage`` (std_msgs/Float64, V) and ``feedback_voltage`` (V).
- pub ``drive_voltage`` (std_msgs/Float64, V): ``clamp(ff + fb, v_min, v_max)``,
  slew-limited; published only while the node is active (output is 0 V before).
- srv ``~/enable`` (std_srvs/SetBool): false ramps the output to the safe voltage (0 V,
  the switch's light-off state) and keeps it there; true resumes.
- lifecycle services (``change_state``, ``get_state``, ...) from rclpy.lifecycle; a
  ``change_state`` request the present state does not offer (any id or label) is
  refused (``success`` false, a WARN in the log and on ``/diagnostics``, the count in
  ``refused_transitions``) instead of killing the process (:meth:`_guard_change_state`).

Pairing: in ``lockstep`` the i-th feedforward is summed with the i-th feedback and the
command time is ``i / rate_hz`` (the plant's sample time), so the output does not depend
on message timing. In ``realtime`` each feedback message (one per displacement sample)
produces one drive with the latest feedforward (both subscriptions keep the newest
message only).

Watchdog (``realtime``; a steady wall-clock timer every ``watchdog_timeout_s`` / 10,
between one control period and 10 ms): when no ``feedback_voltage`` has arrived for
``watchdog_timeout_s`` the node ramps the output to ``safe_voltage_v`` at the slew limit,
publishing the ramp, logs an error and reports ERROR on ``/diagnostics``; once the ramp
ends it stops publishing (the plant holds the safe voltage). A feedback that arrives
while the feedforward is stale (no ``feedforward_voltage`` within ``watchdog_timeout_s``,
e.g. the compensator died) is not used, so a silent compensator trips the watchdog too.
Recovery rule: once ``feedback_voltage`` arrives again with a fresh feedforward, the
driver keeps holding for :data:`RECOVERY_S` of uninterrupted fresh input (no gap over
five periods), so that every node has seen ``drive_held`` true (below) and parked,
also one that was stalled through the whole trip; the next feedback then ends the trip:
the output moves from where the ramp left it to ff + fb at the slew limit, ``drive_held``
turns false and the status returns to OK (``watchdog_count`` keeps the number of
trips).

``drive_held`` (std_msgs/Bool, reliable, transient local, depth 1; published on change
only) tells the other nodes whether the output is held instead of following ff + fb:
true while inactive, disabled (``~/enable`` false) or tripped. While it is true the
controller (realtime) outputs 0 V with its integral cleared and its reference model at
rest at the measured position, and the compensator rests at the measured position: no
integral winds up against an output that cannot move, and after the recovery the first
commands are bumpless (ff of the present position, fb 0); the two nodes then move the
actuator back to the setpoint through the shaper. A controller that restarts without a
setpoint publishes 0 V feedback (see ``fuzzy_pid_controller``), so the drive then
resumes at the feedforward of the held setpoint.

Field limits: ``v_max``, ``v_min`` and ``safe_voltage_v`` are checked at start-up, at
configure and on every live update against both field limits of the PZT layers:
``field_limit_v`` (forward: ``max_field_v_per_m * piezo_thickness_m`` of
``config/actuator.yaml``, 150 V) and ``-depoling_fraction * coercive_field_v`` (a
reverse field beyond a fraction of the coercive field depoles PZT; -39.6 V by default).
A value beyond either is refused with the reason.

Latch: after ``latch_trips`` watchdog trips within ``latch_window_s`` the driver stays at
the safe voltage (ERROR on ``/diagnostics`` with the trip count, ``drive_held`` true)
until ``~/enable`` true or a lifecycle deactivate/activate re-arms it.
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
from fiber_align.control.driver import DriverCore
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


def check_field_limits(p):
    """
    Return ``None`` or why the drive limits in ``p`` break a field limit (V).

    :param p: mapping with ``v_min``, ``v_max``, ``safe_voltage_v``, ``field_limit_v``,
        ``coercive_field_v`` and ``depoling_fraction`` (V, V, V, V, V, 1).
    """
    fwd = float(p['field_limit_v'])
    rev = -float(p['depoling_fraction']) * float(p['coercive_field_v'])
    for k in ('v_max', 'v_min', 'safe_voltage_v'):
        v = float(p[k])
        if not math.isfinite(v):
            return '%s=%r is not finite' % (k, v)
        if v > fwd:
            return ('%s %g V exceeds the field limit %g V (field_limit_v)' % (k, v, fwd))
        if v < rev:
            return ('%s %g V is below the depoling limit %g V (-depoling_fraction %g * '
                    'coercive_field_v %g V)'
                    % (k, v, rev, float(p['depoling_fraction']), float(p['coercive_field_v'])))
    return None


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
        self._guard_change_state()

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

    def _guard_change_state(self):
        """
        Make ``~/change_state`` refuse a transition the present state does not offer.

        rclpy's handler (``LifecycleNodeMixin.__on_change_state`` -> ``__change_state``)
        hands the requested id straight to ``trigger_transition_by_id``, which raises
        ``RCLError`` ("Transition is not registered") for an id that does not start from
        the current state, e.g. ``configure`` (1) while active; the exception leaves the
        service callback, the executor re-raises it and the process dies. This wraps the
        service's callback (the executors call ``Service.callback``): an unavailable id
        or label is answered with ``success`` false, a WARN in the log and on
        ``/diagnostics``; an available one goes to rclpy's handler unchanged.
        """
        srv = getattr(self, '_service_change_state', None)
        if srv is None:
            return
        inner = srv.callback

        def change_state(request, response):
            t = request.transition
            try:
                state = self._state_machine.current_state[1]
                offered = [(i, lbl) for i, lbl, *_ in self._state_machine.available_transitions]
                ok = any((lbl == t.label) if t.label else (i == t.id) for i, lbl in offered)
                if ok:
                    return inner(request, response)
                why = ('refused lifecycle transition %s: not available in state %s '
                       '(available: %s)' % (repr(t.label) if t.label else 'id %d' % t.id,
                                            state, ', '.join('%s (%d)' % (lbl, i)
                                                             for i, lbl in offered)))
            except Exception as exc:  # noqa: BLE001 - no request may kill the driver
                why = 'lifecycle transition %d %r failed: %s' % (t.id, t.label, exc)
            self.refused_transitions += 1
            self.get_logger().warning(why)
            self.health.set_values(refused_transitions=self.refused_transitions)
            self.health.warn(why)
            response.success = False
            return response

        srv.callback = change_state

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
