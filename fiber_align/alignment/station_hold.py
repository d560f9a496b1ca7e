# SPDX-License-Identifier: Apache-2.0
"""
The station's HELD state: a driver of one of the four axes holds its output.

The four-axis form of :mod:`fiber_align.alignment.hold`. When a driver stops driving its
axis (a trip, ``enable`` false, an inactive lifecycle node) while the station is
SEARCHING, PEAKING or TRACKING, the station enters HELD: all four setpoints stay where
they were (the dithers stop too, so no axis moves while one cannot), ``hold_reason`` and
an event name the axes, and it waits. When every driver drives again it waits for the
four axes to be back at the held setpoints, then:

- held while SEARCHING: the search starts again (floor, then the walk);
- held while PEAKING or TRACKING, light at the held point: a re-peak around the last
  estimate (the station's ``switch(True)`` peaking), then TRACKING;
- no light at the held point: the search starts again.

FAULT when the drivers stay down longer than ``driver_down_timeout_s`` (s), or an axis does
not return to its held setpoint once they drive. :class:`StationHold` is a base of
:class:`fiber_align.alignment.station.Station` (its state and parameters; SI: s, m, W).
"""

import numpy as np

from fiber_align.alignment.states import HELD, PEAKING, SEARCHING, TRACKING

AXES4 = ('x_in', 'y_in', 'x_out', 'y_out')


def axes_down(driver_active):
    """Return the axes (names) whose driver is not driving; ``None``: none known down."""
    if driver_active is None:
        return []
    if driver_active is True or driver_active is False:
        return [] if driver_active else list(AXES4)
    return [a for a, up in zip(AXES4, driver_active) if up is False]


class StationHold:
    """The HELD steps of the station (a base of its class; uses its state)."""

    hold_reason = ''

    def _hold(self, t, down):
        """Enter HELD from an active state: keep the four setpoints, say which axes."""
        self._held_from = self.state
        self._held_center = self._hold_center()
        self._held_sp = self.sp.copy()
        self._enter(HELD)
        self._phase = 'down'
        self.hold_reason = ('driver of %s down during %s: all four setpoints held, waiting '
                            'for the re-arm, FAULT after %.1f s'
                            % (', '.join(down), self._held_from,
                               self.p['driver_down_timeout_s']))
        self._log(self.hold_reason)

    def _hold_center(self):
        """Return the estimate a re-peak starts from (m), or None before any light."""
        if self.state == TRACKING:
            return np.asarray(self.aligned, dtype=float).copy()
        if self.state == PEAKING:
            if getattr(self, '_center', None) is not None and len(self._center) == 4:
                return np.asarray(self._center, dtype=float).copy()
            return np.asarray(self.aligned, dtype=float).copy()
        return None

    def _do_held(self, t, pos, pw):
        p = self.p
        self.sp = self._held_sp.copy()
        if self._down:
            if self._phase != 'down':
                self._phase, self._state_t = 'down', t
                self._log('driver down again while returning: setpoints held')
            if self._elapsed(t) > p['driver_down_timeout_s']:
                self._fault('driver inactive: a driver held its output for more than %.1f s '
                            '(during %s) without a re-arm; release or align once it drives'
                            % (p['driver_down_timeout_s'], self._held_from))
            return
        if self._phase == 'down':
            self._log('drivers back after %.0f ms' % (self._elapsed(t) * 1e3))
            if self._held_from == SEARCHING or self._held_center is None:
                return self._resume_search('no light before the trip')
            self._phase, self._return_t = 'return', t
            self._settle_count = 0
        near = np.all(np.abs(pos - self._held_sp) < p['settle_tolerance_m'])
        self._settle_count = self._settle_count + 1 if near else 0
        if self._settle_count >= int(p['settle_samples']) and pw is not None:
            if self.threshold_w is not None and pw <= self.threshold_w:
                return self._resume_search('no light at the held point after the re-arm')
            self.hold_reason = ''
            self.aligned = self._held_center
            self._enter(PEAKING)
            self._log('drivers back: ' + self._start_repeak())
        elif t - self._return_t > p['follow_timeout_s'] and not near:
            a = int(np.argmax(np.abs(pos - self._held_sp)))
            self._fault('actuator does not return to the held setpoint after the re-arm: %s '
                        'at %.2f um, held %.2f um' % (AXES4[a], pos[a] * 1e6,
                                                      self._held_sp[a] * 1e6))

    def _resume_search(self, why):
        self.hold_reason = ''
        self._log('%s: searching again' % why)
        self._enter(SEARCHING)
        self._start_search()
