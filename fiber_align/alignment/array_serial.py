# SPDX-License-Identifier: Apache-2.0
"""
The serial baseline of the array: x and y on channel 1, then roll on channel N, repeated.

:class:`SerialArray` is an :class:`~fiber_align.alignment.array.ArrayMachine` (same floor,
threshold, first-light search, tracking, faults and ``update``); only PEAKING differs, as
a lab would write it with a single-channel aligner:

1. x and y on channel 1, the roll held: the 2-D sequencer's method
   (:class:`~fiber_align.alignment.peak2d.PeakFitMixin`: crosses of settled points,
   paraboloid fit, verify) on ``(x, y)`` and ``P_1``;
2. roll on channel N about channel 1 (channel 1 stays where step 1 put it): three settled
   points along ``y_N``, a parabola of ``ln P_N`` (its curvature fitted, else the prior),
   repeated until the step is within ``converge_tolerance_m``, then a reading there;

and again, until a round gains less than ``serial_min_gain_db`` on both outer channels
(at most ``serial_max_rounds`` rounds). SI units (m, W).
"""

import math

import numpy as np

from fiber_align.alignment import array as ar
from fiber_align.alignment import search2d as s2
from fiber_align.alignment.peak2d import PeakFitMixin
from fiber_align.alignment.states import PEAKING, um
from fiber_align.plant import array_optics as ao


class XYPeaker(PeakFitMixin):
    """peak2d's method on ``(x, y)`` and channel 1, the roll held (for :class:`SerialArray`)."""

    def __init__(self, machine):
        """Take the machine's parameters and the square its held roll leaves (m)."""
        self.m = machine
        self.p = machine.p
        self.roll = ao.pose(machine.aligned, machine.roll_arm_m)[2]
        half = abs(ao.actuators(0.0, 0.0, self.roll, machine.roll_arm_m)[2])
        self.lo = np.array([machine.lo[0], machine.lo[1] + half])
        self.hi = np.array([machine.hi[0], machine.hi[1] - half])
        self.curvature_prior = machine.curvature_prior
        self.iterations = 0
        self.aligned = self.aligned_power_w = self.curvature_per_m2 = self._t = None
        self.sp = np.array(ao.pose(machine.aligned, machine.roll_arm_m)[:2])
        self._phase = ''

    @property
    def floor(self):
        """Return the machine's floor ``(mean, sigma)`` (W)."""
        return self.m.floor

    def start(self, radius):
        """Start a cross of ``radius`` (m) at the machine's aligned point."""
        self._start_pattern(self.sp, radius)

    def step(self, t, pos3, pw2):
        """Advance one period with the three positions (m); return the three setpoints."""
        self._t = t
        x, y, _ = ao.pose(pos3, self.m.roll_arm_m)
        self._do_visit(t, np.array([x, y]), None if pw2 is None else float(pw2[0]))
        return np.array(ao.actuators(self.sp[0], self.sp[1], self.roll, self.m.roll_arm_m))

    def _fault(self, reason):
        if reason.startswith('light lost') and self.m.rounds == 0 and self.iterations == 1:
            return self.m._false_light()
        self.m._fault('channel 1 x-y: ' + reason)

    def _log(self, text):
        self.m._log('channel 1 x-y: ' + text)

    def _start_tracking(self, t):
        self.m._xy_done(self)


class SerialArray(ar.ArrayMachine):
    """Align x-y on channel 1, then roll on channel N, in rounds (module docstring)."""

    method = 'serial'

    def _start_peaking(self, center):
        self._enter(PEAKING)
        self.aligned = np.asarray(center, dtype=float).copy()
        self._start_rounds(self.p['pattern_radius_first_m'])

    def _start_repeak(self):
        self._start_rounds(self.p['repeak_pattern_radius_m'])
        return 'switching on to %s' % um(self.aligned)

    def _start_rounds(self, radius):
        self.rounds, self._last_w, self._center = 0, None, None
        self._run_xy(radius)

    def _run_xy(self, radius):
        self._phase = 'xy'
        self._xy = XYPeaker(self)
        self._xy.start(radius)

    def _do_peaking(self, t, pos, pw):
        if self._phase == 'xy':
            self.sp = self._xy.step(t, pos, self._pw2)
        else:
            self._do_visit(t, pos, self._pw2)

    def _hold_center(self):
        return None if self.aligned is None else np.array(self.aligned, dtype=float)

    def _xy_done(self, peaker):
        """Channel 1 peaked in x-y: keep it; roll on channel N."""
        self.iterations += peaker.iterations
        self.aligned = np.array(ao.actuators(*peaker.aligned, peaker.roll, self.roll_arm_m))
        self._roll_iterations = 0
        self._roll_pattern(self.to_channels(self.aligned), self.p['pattern_radius_first_m']
                           if self.rounds == 0 else self.p['repeak_pattern_radius_m'])

    def _roll_pattern(self, center, radius):
        """Read three points along ``y_N`` (channel 1 held) around ``center`` (channels)."""
        self._phase = 'roll'
        self._roll_c, self._roll_h = center, float(radius)
        pts = [center + s * radius * np.eye(3)[2] for s in (0.0, 1.0, -1.0)]
        self._visit([self.to_actuators(q) for q in pts], self._fit_roll)

    def _fit_roll(self, rows):
        p = self.p
        self.iterations += 1
        self._roll_iterations += 1
        yn = np.array([self.to_channels(r[:3])[2] for r in rows])[:, None]
        ok, w = self._weights(rows[:, 4])
        fit = None
        if ok.sum() >= 3:
            fit = s2.fit_log_paraboloid_groups(yn[ok], rows[ok, 4], ((0,),), w[ok])
            r = p['curvature_ratio_max']
            if fit is not None and not self.curvature_prior / r < fit[1][0] < \
                    self.curvature_prior * r:
                fit = None
        if fit is None and ok.sum() >= 2:
            fit = s2.fit_log_paraboloid_groups(yn[ok], rows[ok, 4], ((0,),), w[ok],
                                               self.curvature_prior)
        if fit is None:
            return self._fault('channel N roll: light lost around %s' % um(self.aligned))
        step = float(fit[0][0]) - self._roll_c[2]
        self._log('channel N roll %d: y_N %.2f um, vertex %.2f um'
                  % (self._roll_iterations, self._roll_c[2] * 1e6, fit[0][0] * 1e6))
        c = self._roll_c.copy()
        c[2] += float(np.clip(step, -p['max_step_m'], p['max_step_m']))
        if abs(step) < p['converge_tolerance_m']:
            return self._visit([self.to_actuators(c)], self._roll_done)
        if self._roll_iterations >= int(p['max_iterations']):
            return self._fault('channel N roll did not converge in %d iterations'
                               % self._roll_iterations)
        self._roll_pattern(c, min(max(p['pattern_radius_gain'] * abs(step),
                                      p['pattern_radius_min_m']), p['pattern_radius_max_m']))

    def _roll_done(self, rows):
        """End a round with both outer channels' readings: another round, or TRACKING."""
        self.aligned = self._visiting.goal.copy()
        now = rows[0, 3:5]
        gain = np.full(2, math.inf) if self._last_w is None else \
            10.0 * np.log10(now / np.maximum(self._last_w, 1e-300))
        self._last_w = now
        self.rounds += 1
        self._log('round %d: channel 1 %+.3f dB, channel N %+.3f dB'
                  % (self.rounds, gain[0], gain[1]))
        if (self.rounds >= 2 and gain.max() < self.p['serial_min_gain_db']) or \
                self.rounds >= int(self.p['serial_max_rounds']):
            self.aligned_power_w = float(math.sqrt(now[0] * now[1]))
            return self._start_tracking(self._t)
        self._run_xy(self.p['repeak_pattern_radius_m'])
