# SPDX-License-Identifier: Apache-2.0
"""
The serial baseline of the station: one side with the 2-D method, then the other, repeated.

:class:`SerialStation` is a :class:`~fiber_align.alignment.station.Station` (same floor,
threshold, first-light search, tracking, faults and ``update``); only PEAKING differs.
From first light it peaks the input side with the 2-D sequencer's method
(:class:`~fiber_align.alignment.peak2d.PeakFitMixin`: crosses of settled points,
paraboloid fit, verify) while the output side holds still, then the output side while the
input side holds, and so on: a side whose peaking gains less than ``serial_min_gain_db``
over the power before it ends the alignment (at most ``serial_max_rounds`` rounds of both
sides). The first peaking of a side starts with ``pattern_radius_first_m``, a re-peak with
``repeak_pattern_radius_m``. SI units.
"""

import math

import numpy as np

from fiber_align.alignment import station as st
from fiber_align.alignment.peak2d import PeakFitMixin
from fiber_align.alignment.states import dbm, PEAKING, um

SIDE_NAMES = ('input', 'output')


class SidePeaker(PeakFitMixin):
    """
    The 2-D method on one side of a station: two of its four axes, the others held.

    :param station: the :class:`SerialStation` it peaks for (parameters, floor, faults).
    :param side: 0 (input: axes 0, 1) or 1 (output: axes 2, 3).
    """

    def __init__(self, station, side):
        """Take the station's parameters and that side's square."""
        self.station = station
        self.side = int(side)
        self.ax = slice(2 * self.side, 2 * self.side + 2)
        self.p = station.p
        self.lo, self.hi = station.lo[self.ax].copy(), station.hi[self.ax].copy()
        self.curvature_prior = station.curvature_prior
        self.iterations = 0
        self.aligned = None
        self.aligned_power_w = None
        self.curvature_per_m2 = None
        self.sp = station.sp[self.ax].copy()
        self._phase = ''
        self._t = None

    @property
    def floor(self):
        """Return the station's floor ``(mean, sigma)`` (W)."""
        return self.station.floor

    def start(self, center, radius):
        """Start peaking around ``center`` (2 values, m) with a cross of ``radius`` (m)."""
        self.iterations = 0
        self._start_pattern(center, radius)

    def step(self, t, pos4, pw):
        """Advance one period with the station's four positions (m); return the 2 setpoints."""
        self._t = t
        self._do_visit(t, pos4[self.ax], pw)
        return self.sp

    def _fault(self, reason):
        if reason.startswith('light lost') and self.station._turns == 0 and \
                self.iterations == 1:
            return self.station._false_light()
        self.station._fault('%s side: %s' % (SIDE_NAMES[self.side], reason))

    def _log(self, text):
        self.station._log('%s side: %s' % (SIDE_NAMES[self.side], text))

    def _start_tracking(self, t):
        self.station._side_done(self)


class SerialStation(st.Station):
    """Align the sides in turn with the 2-D method (see the module docstring)."""

    method = 'serial'

    def _start_peaking(self, center):
        self._enter(PEAKING)
        c = np.asarray(center, dtype=float)
        self.aligned = c.copy()
        self.aligned_power_w = None
        self._sides = (SidePeaker(self, 0), SidePeaker(self, 1))
        self._turns = 0
        self._base_power = None
        self._run_side(0, self.p['pattern_radius_first_m'])

    def _start_repeak(self):
        self._sides = (SidePeaker(self, 0), SidePeaker(self, 1))
        self._turns = 0
        self._base_power = None
        self._run_side(0, self.p['repeak_pattern_radius_m'])
        return 'switching on to %s' % um(self.aligned)

    def _run_side(self, side, radius):
        self._active = self._sides[side]
        self._phase = SIDE_NAMES[side]
        self._active.start(self.aligned[self._active.ax], radius)

    def _do_peaking(self, t, pos, pw):
        side = self._active
        self.sp = self.aligned.copy()
        self.sp[side.ax] = side.step(t, pos, pw)

    def _side_done(self, side):
        """One side converged: keep its point; next side, or stop when it gained nothing."""
        self.iterations += side.iterations
        self.aligned[side.ax] = side.aligned
        gain_db = (math.inf if self._base_power is None else
                   10.0 * math.log10(side.aligned_power_w / max(self._base_power, 1e-300)))
        self._base_power = side.aligned_power_w
        self.aligned_power_w = side.aligned_power_w
        self._turns += 1
        self._log('%s side peaked at %.2f dBm (%+.3f dB)'
                  % (SIDE_NAMES[side.side], dbm(side.aligned_power_w), gain_db))
        rounds_done = self._turns >= 2 * int(self.p['serial_max_rounds'])
        if (self._turns >= 2 and gain_db < self.p['serial_min_gain_db']) or rounds_done:
            k = [s.curvature_per_m2 or self.curvature_prior for s in self._sides]
            self.curvatures_per_m2 = (k[0], k[1])
            return self._start_tracking(self._t)
        nxt = 1 - side.side
        first = self._sides[nxt].aligned is None and self._turns < 2
        self._run_side(nxt, self.p['pattern_radius_first_m'] if first
                       else self.p['repeak_pattern_radius_m'])
