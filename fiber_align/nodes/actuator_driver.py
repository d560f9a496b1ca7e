# SPDX-License-Identifier: Apache-2.0
"""
``actuator_driver``: a managed (lifecycle) node around :class:`DriverCore`.

Sums ``feedforward_voltage`` and ``feedback_voltage`` (std_msgs/Float64, V), clamps and
slew-limits them and publishes ``drive_voltage`` (V) while active (lockstep: the i-th of
each; realtime: the newest, on each feedback, and on each feedforward while the feedback
is late). ``~/enable`` false ramps to the safe voltage. The realtime
watchdog ramps to ``safe_voltage_v`` when the input stops for ``watchdog_timeout_s``,
resumes after :data:`RECOVERY_S` of fresh input, and latches after ``latch_trips`` trips
within ``latch_window_s`` (until ``~/enable`` true or a lifecycle cycle); ``drive_held``
(latched Bool) parks the compensator and the controller for a bumpless resume. The
voltage limits are checked against both field limits of the PZT layers. ``backend``
``mdt693b`` drives a Thorlabs MDT693B channel (:mod:`fiber_align.nodes._driver_output`);
``sensorless`` drives the feedforward alone. The full behaviour, with the reasons:
docs/ros_interface.md, section "actuator_driver".
"""

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
from fiber_align.nodes._cycle import CycleStats
from fiber_align.nodes import _driver_output as do

NODE_NAME = 'actuator_driver'
#: Topics this node publishes (relative names; see ``_common.LocalBus``).
PUBLISHES = ('drive_voltage', 'drive_held', 'drive_voltage_readback')
AREA_FILES = ('driver.yaml',)
#: Uninterrupted fresh input (s, wall) the driver waits for before it ends a trip.
RECOVERY_S = 0.02


class ActuatorDriverNode(do.DriverParameters, do.DeviceBackend, LifecycleNode):
    """Lifecycle transport around :class:`DriverCore`."""

    def __init__(self, bus=None, **kwargs):
        """
        Declare parameters (defaults from config/); nothing is created until configure.

        :param bus: the :class:`~fiber_align.nodes._common.LocalBus` of a composed
            process, or ``None``.
        """
        super().__init__(NODE_NAME, **kwargs)
        self.bus = bus
        self.slack = c.slack_of(bus)
        d = c.node_defaults(NODE_NAME, AREA_FILES)
        do.declare_all(self, d)
        self.backend = self.get_parameter('backend').value
        self.sensorless = bool(self.get_parameter('sensorless').value)
        why = check_field_limits(self._core_params())
        if why:
            raise ConfigError('actuator_driver: %s' % why)
        self.add_on_set_parameters_callback(self._on_set)
        self.core = None
        self.pub = None
        self.out = None                 # DeviceOutput of the mdt693b backend
        self.pub_rb = None
        self.lost = None                # one-line reason once the device is lost
        self._rb_t = None
        self.enabled = True
        self.active = False
        self.n_drive = 0
        self.ff_q = []
        self.fb_q = []
        self._msg = Float64()
        self.ff_latest = 0.0
        self.t_ff = self.t_fb = None    # realtime: wall time (s) of the latest ff, fb
        self.i = 0
        self._subs = []
        self._timer = None
        self._srv = None
        self._t_fresh = None            # realtime: start (s) of fresh input after a trip
        self._t_fresh_last = 0.0
        self.held = None                # last value published on drive_held
        self.pub_held = c.Pub(self, Bool, 'drive_held', c.LATCHED_QOS, bus, latched=True)
        self._set_held(True, 'unconfigured')
        self.health = c.Health(self, self.get_parameter('diagnostics_period_s').value,
                               slack=self.slack)
        self.health.status(c.WARN, 'unconfigured: output 0 V')
        self.refused_transitions = 0
        c.guard_change_state(self)

    # -- lifecycle ------------------------------------------------------------------
    def _refuse(self, why):
        self.get_logger().error('cannot configure: %s' % why)
        self.health.status(c.ERROR, why)
        self.health.error(why)                          # on /diagnostics at once
        self.core = None
        return TransitionCallbackReturn.FAILURE

    def on_configure(self, state):
        """Build the core, open the device (mdt693b) and the transport; nothing published."""
        p = self._core_params()
        why = self._check_core(p)
        if why:
            return self._refuse(why)
        self.period_s = 1.0 / float(self.get_parameter('rate_hz').value)
        self.core = DriverCore.from_params(p, ramp_period_s=self.period_s)
        self.lockstep = self.get_parameter('sync_mode').value == 'lockstep'
        why = self._open_device(Float64)
        if why:
            return self._refuse(why)
        self.pub = c.Pub(self, Float64, 'drive_voltage', c.CONTROL_QOS, self.bus,
                         slack=self.slack)
        qos = c.sample_qos(self.lockstep)
        self._subs = [
            c.subscription(self, Float64, 'feedforward_voltage', self._on_ff, qos, self.bus)]
        if not self.sensorless:
            self._subs.append(c.subscription(self, Float64, 'feedback_voltage', self._on_fb,
                                             qos, self.bus))
        self._srv = self.create_service(SetBool, '~/enable', self._on_enable)
        if not self.lockstep:
            self._timer = self.create_timer(self.watchdog_period_s(), self._on_tick,
                                            clock=Clock(clock_type=ClockType.STEADY_TIME))
            self.health.cycle = CycleStats(1.0 / self.period_s)     # feedforward to drive
        self.health.status(c.OK, 'configured (inactive): output %g V' % self.core.v)
        self._update_values()
        return TransitionCallbackReturn.SUCCESS

    def watchdog_period_s(self):
        """Return the watchdog period (s): one control period (each ramp step is one)."""
        return self.period_s

    def on_activate(self, state):
        """Start publishing drive commands (a lifecycle cycle re-arms a latched watchdog)."""
        if self.core.latched:
            self.core.rearm()
            self.get_logger().info('watchdog latch re-armed by activate')
        self.core.restart_watchdog()    # the inactive time is no loss of input
        self.active = True
        self._set_held(not self.enabled or self.core.tripped, 'activated')
        if self.lockstep:
            self._pair()        # the pairs that came between configure and activate
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
        if self._ramp_device():
            return TransitionCallbackReturn.ERROR       # on_error closes the device
        safe = self.core.safe if self.core else 0.0
        if self.out is not None:
            self._publish(safe)                         # the device is at it already
            self.out.start()                            # read-back only (nothing pending)
        self.health.status(c.OK, 'inactive: output %g V' % safe)
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Destroy the transport and the core; close the device (the output stays)."""
        if self.lost is not None:
            return TransitionCallbackReturn.ERROR
        self._teardown()
        self.health.status(c.WARN, 'unconfigured: output 0 V')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        """Ramp the device to the safe voltage, then tear down."""
        self._ramp_device()
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state):
        """Close a lost device and end unconfigured (a later configure reconnects)."""
        why = self.lost or 'a transition failed'
        self._teardown()
        self.health.status(c.ERROR, 'device lost: %s; unconfigured: a configure reconnects'
                           % why)
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self):
        self._close_device()
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
        self.ff_q, self.fb_q = [], []
        self._set_held(True, 'unconfigured')

    # -- control --------------------------------------------------------------------
    def _on_enable(self, request, response):
        """Enable (true) or disable (false: ramp to the safe voltage) the output."""
        if self.enabled and not request.data and self.core is not None:
            self.core.start_safe_ramp(self._now())
        self.enabled = bool(request.data)
        if self.enabled and self.core is not None and (self.core.latched
                                                       or self.core.trip_times):
            # the operator's enable acknowledges the trips so far (and re-arms a latch)
            if self.core.latched:
                self.health.status(c.OK, 'active' if self.active else 'inactive')
            self.core.rearm()
            self.get_logger().info('watchdog re-armed by ~/enable (trip history cleared)')
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
            if self.sensorless:
                self._realtime(0.0)
            elif self.t_fb is not None and self.core is not None and not self.core.tripped \
                    and 1.5 * self.period_s < self.t_ff - self.t_fb < self.core.timeout:
                # the feedback is late (a stalled controller): follow the feedforward
                # with the last feedback, the watchdog counting from that feedback's
                # time; held until it came, the drive jumped by the whole stall's
                # feedforward (20 ms mid-move: 36 V, a 70-74 um peak for a 50 um target)
                self._realtime(self.fb_last, self.t_fb)

    def _on_fb(self, msg):
        if self.lockstep:
            self.fb_q.append(msg.data)
            self._pair()
        else:
            self.t_fb = self._now()
            self.fb_last = msg.data
            self._realtime(msg.data)

    def _realtime(self, fb, t_input=None):
        """
        Realtime: drive the newest feedforward plus ``fb`` (V) unless held.

        :param t_input: the time (s) of the stalest input (see ``DriverCore.command``).
        """
        now = self._now()
        core = self.core
        if core is not None and core.timeout > 0 and (
                self.t_ff is None or now - self.t_ff > core.timeout):
            return      # stale feedforward: leave it to the watchdog (docstring)
        if core is not None and core.latched:
            return      # latched: only ~/enable or a lifecycle cycle ends it
        if core is not None and core.tripped and self.enabled and not self._recovered(now):
            return      # hold until the input has been fresh for RECOVERY_S (docstring)
        self._command(self.ff_latest, fb, now, t_input)
        if self.health.cycle is not None and self.t_ff is not None:
            self.health.cycle.record(self._now() - self.t_ff)

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
        # inactive: keep the pairs (a plant that started at configure, when this
        # publisher appeared, had its first sample's drive dropped and waited forever)
        while self.active and self.ff_q and self.fb_q:
            ff = self.ff_q.pop(0)
            fb = self.fb_q.pop(0)
            t = self.i * self.period_s
            self.i += 1
            self._command(ff, fb, t)

    def _command(self, ff, fb, t, t_input=None):
        core = self.core
        if core is None or not self.active:
            return      # inactive: the output ramps to, and stays at, the safe voltage
        if self.enabled:
            was_tripped = core.tripped
            v = core.command(ff, fb, t, t_input)
            if was_tripped:
                msg = 'input is back: watchdog cleared after trip %d' % core.watchdog_count
                self._set_held(not self.active, 'input is back')
                self.health.status(c.OK, 'active')
                self.health.set_values(watchdog_count=core.watchdog_count)
                self.get_logger().info(msg)
        else:
            v = core.ramp_safe(t)
        if self.active:
            self._publish(v)

    def _on_tick(self):
        """Realtime watchdog (wall clock)."""
        core = self.core
        if core is not None and self.out is not None:
            self._poll_device(Float64)
            core = self.core            # None once a lost device ended in ERROR
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
            ages = ', '.join('%s %s' % (k, 'never' if tk is None else '%.3f s old' % (t - tk))
                             for k, tk in (('feedforward', self.t_ff), ('feedback', self.t_fb)))
            msg = ('watchdog: no fresh feedback_voltage and feedforward_voltage for %.3g s '
                   '(%s): ramping to %g V' % (core.timeout, ages, core.safe))
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
    fb_last = 0.0                       # realtime: the newest feedback (V)
    n_rb = 0

    def _publish(self, v):
        msg = self._msg
        msg.data = float(v)
        self.pub.publish(msg)
        self._last_pub = float(v)
        self.n_drive += 1
        if self.out is not None:
            self.out.submit(msg.data)

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
        if self.out is not None:
            self.health.set_values(**self.out.values())

    def sent_counts(self):
        """Return published message counts per topic."""
        out = {'drive_voltage': self.n_drive}
        if self.backend == 'mdt693b':
            out['drive_voltage_readback'] = self.n_rb
        return out


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
