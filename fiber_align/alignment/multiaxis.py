# SPDX-License-Identifier: Apache-2.0
"""
What the 2-D and the station sequencers share each period: the health checks, IDLE, RELEASING.

:class:`MultiAxis` is a base of :class:`fiber_align.alignment.sequencer2d.Sequencer2D`
and :class:`fiber_align.alignment.station.Station` (their state, parameters, setpoints
``sp`` and positions as numpy arrays, one entry per axis named in ``AXIS_NAMES``; SI: s,
m, W).
"""

import numpy as np

from fiber_align.alignment.states import IDLE


class MultiAxis:
    """Sensor and follow checks, IDLE and RELEASING over several axes (a base class)."""

    #: the axes' names in the order of ``sp`` and the positions (for the fault text)
    AXIS_NAMES = ()

    def _silent_or_stuck(self, t, pos):
        """Return True (and fault) when a reading is missing or an axis does not follow."""
        p = self.p
        t0 = self._state_t if self._state_t is not None else t
        for key, what in (('p', 'optical power'), ('y', 'displacement')):
            last = max(self._last[key] if self._last[key] is not None else t0, t0)
            if t - last > p['sensor_timeout_s']:
                self._fault('sensor silent: no %s reading for %.0f ms'
                            % (what, (t - last) * 1e3))
                return True
        if pos is None:
            return False
        err = np.abs(pos - self.sp)
        if np.any(err > p['follow_error_m']):
            if self._follow_since is None:
                self._follow_since = t
            elif t - self._follow_since > p['follow_timeout_s']:
                a = int(np.argmax(err))
                self._fault('driver inactive or actuator stuck: %s at %.1f um does not '
                            'follow its setpoint %.1f um for %.0f ms'
                            % (self.AXIS_NAMES[a], pos[a] * 1e6, self.sp[a] * 1e6,
                               (t - self._follow_since) * 1e3))
                return True
        else:
            self._follow_since = None
        return False

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
