# SPDX-License-Identifier: Apache-2.0
"""
What the 2-D and the station sequencers share: the period's step, IDLE, RELEASING, TRACKING.

:class:`MultiAxis` is a base of :class:`fiber_align.alignment.sequencer2d.Sequencer2D`
and :class:`fiber_align.alignment.station.Station` (their state, parameters, setpoints
``sp`` and positions as numpy arrays, one entry per axis named in ``AXIS_NAMES``; SI: s,
m, W). Each ``update`` of theirs is :meth:`MultiAxis._update` with their positions.
"""

import math

import numpy as np

from fiber_align.alignment.states import ACTIVE, IDLE, PEAKING, SEARCHING, TRACKING
from fiber_align.alignment.tracking import Tracker

#: Share of the realtime path's rate the search walks at, at most: the rest is room for
#: the acceleration limit at the turns of the path.
PATH_RATE_SHARE = 0.9


def axes_down(names, driver_active):
    """Return the names of the axes whose driver is not driving (``driver_active`` False)."""
    if driver_active is None:
        return []
    if driver_active is True or driver_active is False:
        return [] if driver_active else list(names)
    return [a for a, up in zip(names, driver_active) if up is False]


class MultiAxis:
    """The period's step, IDLE, RELEASING and TRACKING over several axes."""

    #: the dithers of TRACKING: (parameter naming the frequency (Hz), axes of the circle)
    DITHERS = ()

    def _init_axes(self, p, park, lo, hi, period_s, path_rate_m_per_s):
        """Set the square (m), the period (s) and the search speed (m/s), then the machine."""
        if period_s is None:
            raise ValueError('period_s (s) is required: the period of the update calls, '
                             '1 / the graph\'s rate_hz')
        self.lo, self.hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        self.park = np.asarray(park, dtype=float)
        self.period_s = float(period_s)
        self.search_speed = float(p['search_speed_m_per_s'])
        if path_rate_m_per_s is not None and path_rate_m_per_s > 0:
            self.search_speed = min(self.search_speed, PATH_RATE_SHARE * path_rate_m_per_s)
        self.aligned = None
        self.sp = self.park.copy()
        self._prev_pos = None
        self._init_machine(p)

    @property
    def setpoint(self):
        """Return the last setpoints (m), one per axis."""
        return tuple(float(v) for v in self.sp)

    def _down_names(self, driver_active):
        return axes_down(self.AXIS_NAMES, driver_active)

    def _update(self, t_s, positions_m, power_w, driver_active):
        """
        Advance one control period; return the setpoints (m).

        :param positions_m: the measured positions (m), or None (or a None in them).
        :param driver_active: None (as the drivers published), a bool for every driver,
            or one bool per axis: False when that driver is not driving (HELD).
        """
        t = float(t_s)
        self.dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        pos = None
        if positions_m is not None and all(v is not None and math.isfinite(v)
                                           for v in positions_m):
            pos = np.asarray(positions_m, dtype=float)
            self._last['y'] = t
        pw = None if power_w is None or not math.isfinite(power_w) else float(power_w)
        if pw is not None:
            self._last['p'] = t
        if driver_active is None and not self.drivers.pending:
            # what the drivers published; pending: a re-activated driver whose drive_held
            # false is on its way is no reason to hold (one that stays held does not follow)
            driver_active = self.drivers.each
        down = self._down_names(driver_active)
        self._driver_up = not down
        if self.state in ACTIVE and down:
            self._hold(self.drivers.reason, down)
        if self.state in ACTIVE and self._silent_or_stuck(t, pos):
            return self.setpoint
        if pos is None:
            pos = self._prev_pos if self._prev_pos is not None else self.sp.copy()
        self._rest = self._prev_pos is not None and np.all(
            np.abs(pos - self._prev_pos) < self.p['settle_tolerance_m'])
        self._prev_pos = pos
        getattr(self, '_do_' + self.state.lower())(t, pos, pw)
        if self.state == PEAKING:
            self.peak_samples += 1
        elif self.state == SEARCHING:
            self.search_samples += 1
        self.sp = np.minimum(np.maximum(self.sp, self.lo), self.hi)
        return self.setpoint

    def _start_tracking(self, t):
        """TRACKING from the aligned point: circles of ``dither_radius_m`` (``DITHERS``)."""
        p = self.p
        self._enter(TRACKING)
        self._tracker = Tracker(self.aligned, self._curvatures(), p['dither_radius_m'],
                                [(p[key], axes) for key, axes in self.DITHERS], t, p,
                                self.lo, self.hi, self.aligned_power_w, p['power_lag_s'])

    def _do_tracking(self, t, pos, pw):
        sp = self._track(t, pos, pw)
        if sp is not None:
            self.aligned = self._tracker.xhat.copy()
            self.sp = sp

    def _start_search(self):
        self._phase = 'floor'
        self._floor_buf = list(self._idle_buf)

    def _aligned_point(self):
        return self.aligned

    def _do_idle(self, t, pos, pw):
        self.sp = self.park.copy()
        if not self._rest:
            self._idle_buf = []
        elif pw is not None:
            self._idle_buf.append(pw)
            del self._idle_buf[:-int(self.p['floor_samples'])]

    def _do_releasing(self, t, pos, pw):
        self.sp = self.park.copy()
        if np.all(np.abs(pos - self.park) < self.p['release_tolerance_m']) or \
                self._elapsed(t) > self.p['release_timeout_s']:
            self._enter(IDLE)
