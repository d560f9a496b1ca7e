# SPDX-License-Identifier: Apache-2.0
"""
The sequencer's HELD state: the driver holds its output, the sequencer waits for it.

A driver that holds its output (a watchdog trip, ``enable`` false, an inactive or
unconfigured lifecycle node: ``drive_held`` true) while the sequencer is SEARCHING,
PEAKING or TRACKING does not end the alignment. The sequencer enters HELD: it keeps its
last setpoint (nothing jumps when the driver resumes), says why (an event and
``hold_reason``) and waits. When the driver drives again (the re-arm: ``enable`` true,
a lifecycle cycle, or the input back after a trip) it waits for the actuator to return
to the held setpoint, then goes on from there:

- a trip before any light (SEARCHING): the search starts again;
- a trip in the first sweep through the peak: the sweep goes on from the held point,
  with the readings taken before the trip;
- a trip after a fit (PEAKING) or in TRACKING: a local re-peak (the +-``repeak_span_m``
  sweep with the known curvature) around the last peak estimate, then TRACKING;
- no light at the held point after the return (the slot moved, the source went off): the
  search starts again.

FAULT only when the driver stays down for longer than ``driver_down_timeout_s`` (s), or
the actuator does not return to the held setpoint once the driver drives again.
:class:`Hold` is a base of :class:`fiber_align.alignment.sequencer.Sequencer` (its state
and parameters; SI: s, m, W).
"""

from fiber_align.alignment.states import HELD, PEAKING, SEARCHING, TRACKING


class Hold:
    """The HELD steps of the sequencer (a base of its class; uses its state)."""

    hold_reason = ''

    def _hold(self, t, y, why=''):
        """
        Enter HELD from an active state: keep the setpoint, note what was going on.

        :param why: what the driver's messages say of it (``drivers.reason``), or ''.
        """
        self._held_from, self._held_phase = self.state, self._phase
        self._goal_before_hold = getattr(self, '_goal', None)
        self._enter(HELD)
        self._phase = 'down'
        self.hold_reason = ('driver down during %s at %.2f um%s: setpoint held, waiting for '
                            'the re-arm (enable or a lifecycle cycle), FAULT after %.1f s'
                            % (self._held_from, self._setpoint * 1e6,
                               ' (%s)' % why if why else '',
                               self.p['driver_down_timeout_s']))
        self._log(self.hold_reason)

    def _do_held(self, t, y, pw):
        p = self.p
        if not self._driver_up:
            if self._phase != 'down':               # down again while returning
                self._phase, self._state_t = 'down', t
                self._log('driver down again while returning: setpoint held')
            if self._elapsed(t) > p['driver_down_timeout_s']:
                self._fault('driver inactive: the driver held its output for more than '
                            '%.1f s (since %.3f s, during %s at %.2f um) without a re-arm '
                            '(enable or a lifecycle cycle); release or align once it drives'
                            % (p['driver_down_timeout_s'], self._state_t, self._held_from,
                               self._setpoint * 1e6))
            return
        if self._phase == 'down':
            self._log('driver back after %.0f ms' % (self._elapsed(t) * 1e3))
            if self._held_from == SEARCHING:
                self._resume_search('no light before the trip')
                return
            self._phase, self._return_t, self._return_from = 'return', t, y
            self._settle_count = 0
        self._goal = self._setpoint
        if self._settled(y):
            if pw is None:
                return                              # decide on a reading
            if self.threshold_w is not None and pw <= self.threshold_w:
                self._resume_search('no light at the held point %.2f um after the re-arm'
                                    % (self._setpoint * 1e6))
            else:
                self._resume_peak(t)
        elif t - self._return_t > p['settle_timeout_s'] + abs(
                self._setpoint - self._return_from) / p['search_speed_m_per_s']:
            self._fault('actuator does not return to the held setpoint %.2f um after the '
                        're-arm (at %.2f um)' % (self._setpoint * 1e6, y * 1e6))

    def _resume_search(self, why):
        self.hold_reason = ''
        self._log('%s: searching again' % why)
        self._resumed = True            # align and switch replace this resume
        self._enter(SEARCHING)
        self._start_search()

    def _resume_peak(self, t):
        """Re-peak from the held point: go on with the first sweep, or a local one."""
        self.hold_reason = ''
        self._resumed = True            # align and switch replace this re-peak
        phase = self._held_phase
        if self._held_from == PEAKING and phase == 'sweep' and self._first_sweep:
            # the readings before the trip stay valid: the sweep goes on from here
            self.state, self._state_t, self._phase = PEAKING, t, 'sweep'
            self._follow_since = None
            self.events.append((t, PEAKING, 'driver back: the sweep goes on'))
            return
        if self._held_from == TRACKING:
            center = self._x_hat
        elif phase in ('goto', 'goto_peak', 'verify'):
            center = self._goal_before_hold
        else:
            center = self._local_center
        self._enter(PEAKING)
        self._refits, self._goto_phase = 0, None
        self._start_local(center)
        self._log('driver back: local re-peak around %.2f um' % (center * 1e6))
