# SPDX-License-Identifier: Apache-2.0
"""
What the multi-axis sequencers share: the search walk, the re-peak, PEAKING's start.

:class:`MultiAxis` is a base of :class:`fiber_align.alignment.sequencer2d.Sequencer2D`
and :class:`fiber_align.alignment.station.Station` (their state, parameters, setpoints
``sp`` and positions as numpy arrays, one entry per axis named in ``AXIS_NAMES``; SI: s,
m, W).
"""

import numpy as np

from fiber_align.alignment.states import dbm, PEAKING, SEARCHING, um

#: Share of the realtime path's rate the search walks at, at most: the rest is room for
#: the acceleration limit at the turns of the path.
PATH_RATE_SHARE = 0.9


class MultiAxis:
    """The search walk, the re-peak and PEAKING's start over several axes."""

    #: True: past first light the walk goes on to the pass's brightest reading (at most
    #: ``crest_max_samples``); False: PEAKING starts at the brightest reading so far
    CREST = False
    #: the phase of the walk to first light (``status()['phase']``)
    SEARCH_PHASE = 'search'

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
        #: the walk (m) over which first light is confirmed: the search path's design
        self.confirm_chord_m = (int(p['confirm_samples']) + 1) * self.search_speed * self.period_s
        self.aligned = None
        self.sp = self.park.copy()
        self._init_machine(p)

    def update(self, t_s, positions_m, power_w, driver_active=None):
        """
        Advance one control period; return the setpoints (m), one per axis.

        :param t_s: time of the readings (s).
        :param positions_m: the measured positions (m) in ``AXIS_NAMES`` order, or None.
        :param power_w: the detector's reading (W), or None.
        :param driver_active: None (as the drivers published), a bool for every driver,
            or one bool per axis: False when that driver is not driving (HELD).
        """
        return self._update(t_s, positions_m, power_w, driver_active)

    def status(self):
        """Return a dict of the state (for topics, diagnostics and reports; SI)."""
        al = self.aligned
        return dict(state=self.state, phase=self._phase, fault_reason=self.fault_reason,
                    setpoints_m=list(self.setpoint),
                    aligned_m=None if al is None else [float(v) for v in al],
                    threshold_w=self.threshold_w, hold_reason=self.hold_reason,
                    peak_samples=self.peak_samples,
                    search_samples=self.search_samples, iterations=self.iterations)

    def _driver_input(self):
        # pending (a re-activated driver's drive_held false on its way): no reason to hold
        return None if self.drivers.pending else self.drivers.each

    def _repeak_after_hold(self, t, center):
        self.aligned = center
        self._enter(PEAKING)
        self._log('drivers back: ' + self._start_repeak())

    def _start_repeak(self):
        """Re-peak around the last aligned point (``switch(True)``, back from HELD)."""
        self._history = []
        self._start_pattern(self.aligned, self.p['repeak_pattern_radius_m'])
        return 'switching on to %s' % um(self.aligned)

    # ---- SEARCHING: the floor, then the machine's path to first light ---------------
    def _do_searching(self, t, pos, pw):
        p = self.p
        if self._elapsed(t) > p['search_timeout_s']:
            self._fault('no light found: search timed out after %.0f ms at %s (threshold '
                        '%.1f dBm)' % (self._elapsed(t) * 1e3, um(pos), dbm(self.threshold_w)))
            return
        if self._phase == 'floor':
            bright = self._measure_floor(self._rest, pw)
            if bright is None:
                return
            if bright:
                self.floor = (0.0, p['floor_max_w'] / max(p['threshold_sigma'], 1.0))
                self.first_light_t = t
                self._path = None           # lit at the start: no walk (yet)
                self._start_peaking(pos)
                return
            self._path = self.search_path(pos)
            self._phase = self.SEARCH_PHASE
            self._confirm = 0
            self._best = (0.0, pos)
        if pw is not None and pw > self._best[0]:
            self._best = (pw, pos)
        if self._phase == 'crest':
            # past first light the pass goes on to its brightest reading (it crosses the
            # lit region): a far better start for the fit than the threshold's edge
            self._crest += 1
            if pw is None or pw < self._best[0] or self._crest >= int(p['crest_max_samples']):
                self._log('first light %.1f dBm at %s (threshold %.1f dBm)' % (
                    dbm(self._best[0]), um(self._best[1]), dbm(self.threshold_w)))
                self._start_peaking(self._best[1])
                return
        elif pw is not None and pw > self.threshold_w:
            self._confirm += 1
            if self._confirm >= int(p['confirm_samples']):
                self.first_light_t = t
                if not self.CREST:
                    return self._start_peaking(self._best[1])
                self._phase, self._crest = 'crest', 0
        else:
            self._confirm = 0
        if self._path.done:
            if np.all(np.abs(pos - self.sp) < 4 * p['settle_tolerance_m']):
                self._fault(self._no_light_text())
            return
        self.sp = np.asarray(self._path.advance(self.search_speed * self.dt), dtype=float)

    def _false_light(self):
        """Nothing lit around the first-light point: a noise spike; walk on (same path)."""
        self._log('no light around the first-light point: noise, searching on')
        self.state = SEARCHING
        self.events.append((self._t, SEARCHING, 'resumed'))
        self._phase, self._confirm, self._best = self.SEARCH_PHASE, 0, (0.0, self.sp.copy())
        if getattr(self, '_path', None) is None:     # it was lit at the start: no walk yet
            self._path = self.search_path(self.sp)

    # ---- PEAKING -------------------------------------------------------------------
    def _start_peaking(self, center):
        self._enter(PEAKING)
        self._history = []
        self._start_pattern(center, self.p['pattern_radius_first_m'])

    def _do_peaking(self, t, pos, pw):
        self._do_visit(t, pos, pw)

    def _start_search(self):
        self._phase = 'floor'
        self._floor_buf = list(self._idle_buf)
