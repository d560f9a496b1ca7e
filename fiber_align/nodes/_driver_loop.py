# SPDX-License-Identifier: Apache-2.0
"""
The per-message part of ``actuator_driver``: inputs, commands, watchdog, ``drive_held``.

:class:`DriverLoop` is a mixin of the node (its ``core``, ``rt``, ``health``, ``pub``,
``active``, ``enabled``, ``lockstep``); the realtime input rules are
:class:`fiber_align.control.realtime.DriverStep`'s, the limits and the watchdog
:class:`fiber_align.control.driver.DriverCore`'s. SI units (V, s).
"""

import time

from std_msgs.msg import Bool, Float64

from fiber_align.nodes.ros.diagnostics import ERROR, OK


class DriverLoop:
    """Lockstep pairing, realtime commands, the watchdog tick and the reports (mixin)."""

    def _on_enable(self, request, response):
        """Enable (true) or disable (false: ramp to the safe voltage) the output."""
        if self.enabled and not request.data and self.core is not None:
            self.core.start_safe_ramp(self._now())
        self.enabled = bool(request.data)
        if self.enabled and self.core is not None and (self.core.latched
                                                       or self.core.trip_times):
            # the operator's enable acknowledges the trips so far (and re-arms a latch)
            if self.core.latched:
                self.health.status(OK, 'active' if self.active else 'inactive')
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
        elif self.core is not None:
            self._realtime(self.rt.feedforward(msg.data, self._now(), self.enabled,
                                               self.sensorless))

    def _on_fb(self, msg):
        if self.lockstep:
            self.fb_q.append(msg.data)
            self._pair()
        elif self.core is not None:
            self._realtime(self.rt.feedback(msg.data, self._now(), self.enabled))

    def _realtime(self, cmd):
        """Realtime: drive ``cmd`` = ``(ff, fb, t_input)`` of :class:`DriverStep`, if any."""
        if cmd is None:
            return
        self._command(cmd[0], cmd[1], self._now(), cmd[2])
        if self.health.cycle is not None and self.rt.t_ff is not None:
            self.health.cycle.record(self._now() - self.rt.t_ff)

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
                self.health.status(OK, 'active')
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
                             for k, tk in (('feedforward', self.rt.t_ff),
                                           ('feedback', self.rt.t_fb)))
            msg = ('watchdog: no fresh feedback_voltage and feedforward_voltage for %.3g s '
                   '(%s): ramping to %g V' % (core.timeout, ages, core.safe))
            self.get_logger().error(msg)
            self.health.status(ERROR, msg)
            self.health.set_values(watchdog_count=core.watchdog_count)
            self.health.error(msg)
            self._set_held(True, 'watchdog')
            self.rt.tripped()
            if core.latched:
                msg = ('watchdog latched after %d trips within %g s: output held at %g V '
                       'until ~/enable true or a lifecycle deactivate/activate'
                       % (len(core.trip_times), core.latch_window_s, core.safe))
                self.get_logger().error(msg)
                self.health.status(ERROR, msg)
                self.health.error(msg)
        if core.tripped and (v != was_at or self._last_pub != v):
            self._publish(v)
        self._ticks += 1
        if self._ticks % 20 == 0:
            self._update_values()

    _ticks = 0
    _last_pub = None
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
