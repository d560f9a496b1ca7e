# SPDX-License-Identifier: Apache-2.0
"""
The sequencer's PEAKING state: one sweep through the peak and a fit of ``ln P``.

The Gaussian mode overlap makes ``ln P`` exactly quadratic in the offset, so a
three-parameter least-squares fit of one sweep's samples against the measured
displacement (:func:`~fiber_align.alignment.search2d.fit_log_paraboloid_groups`, one
group of one axis) locates the peak; the sequencer moves to the vertex,
waits for the loop to settle and checks the power against the fitted peak, re-sweeping
locally on a miss. :class:`Peaking` holds these steps of
:class:`fiber_align.alignment.sequencer.Sequencer` (its state and parameters, SI: s, m, W;
dB only for ratios).
"""

import math

import numpy as np

from fiber_align.alignment.search2d import fit_log_paraboloid_groups
from fiber_align.alignment.states import PEAKING


class Peaking:
    """The PEAKING steps of the sequencer (a base of its class; uses its state)."""

    def _start_peaking(self, t, y, pw):
        self._enter(PEAKING)
        self.first_light_t = t
        self._phase = 'sweep'
        self._sweep_end = self.p['range_max_m']
        self._sweep_speed = self.p['peak_speed_m_per_s']
        self._samples = []
        self._refits = 0
        self._first_sweep = True
        self._setpoint = max(self._setpoint, y)

    def _start_local(self, center, span=None):
        """Begin a local sweep over ``center +- span`` (m; None: ``repeak_span_m``)."""
        p = self.p
        if span is None:
            span, self._widened = p['repeak_span_m'], 0
        lo = max(center - span, p['range_min_m'])
        self._sweep_end = min(center + span, p['range_max_m'])
        self._sweep_speed = p['repeak_speed_m_per_s']
        self._samples = []
        self._first_sweep, self._local_center = False, center
        self._goal = lo
        self._phase = 'goto_sweep'

    def _widen(self, yy):
        """
        Sweep again twice as wide, or search again: a local sweep (over ``yy``, m) had no peak.

        The held or last aligned point need not match the fiber any more (a re-plugged
        bimorph starts from rest, its feedforward's memory does not): after
        ``repeak_widen_max`` wider sweeps the search starts again instead of a FAULT.
        """
        p, center = self.p, self._local_center
        n = getattr(self, '_widened', 0)
        what = 'no peak in the %d samples over %.1f..%.1f um' % (
            len(yy), yy.min() * 1e6, yy.max() * 1e6)
        if n >= int(p['repeak_widen_max']):
            self._search_again(what)
            return
        span = p['repeak_span_m'] * 2.0 ** (n + 1)
        self._log('%s: sweeping again over %.2f +- %.1f um' % (what, center * 1e6, span * 1e6))
        self._start_local(center, span)
        self._widened = n + 1

    def _settled(self, y):
        if abs(y - self._goal) < self.p['settle_tolerance_m']:
            self._settle_count += 1
        else:
            self._settle_count = 0
        return self._settle_count >= int(self.p['settle_samples'])

    def _do_peaking(self, t, y, pw):
        p = self.p
        if self._phase in ('goto', 'goto_sweep', 'goto_peak'):
            if not hasattr(self, '_goto_t') or self._goto_phase != self._phase:
                self._goto_t, self._goto_phase, self._settle_count = t, self._phase, 0
            ramp = p['switch_ramp_time_s'] if self._phase == 'goto' else 0.0
            tau = t - self._goto_t
            if tau < ramp:                      # raised-cosine move (switch on)
                x0 = self._switch_from
                self._setpoint = x0 + (self._goal - x0) * 0.5 * (
                    1.0 - math.cos(math.pi * tau / ramp))
                return
            self._setpoint = self._goal
            if self._settled(y):
                if self._phase == 'goto':        # switch-on: re-peak locally
                    self._start_local(self._goal)
                elif self._phase == 'goto_sweep':
                    self._phase = 'sweep'
                else:
                    self._phase, self._verify = 'verify', []
                self._goto_phase = None
            elif t - self._goto_t > p['settle_timeout_s'] + abs(
                    self._goal - y) / p['peak_speed_m_per_s']:
                if self._phase == 'goto_peak':   # accept, the tracker will finish it
                    self._phase, self._verify = 'verify', []
                    self._goto_phase = None
                else:
                    self._fault('actuator does not settle at %.2f um (at %.2f um)'
                                % (self._goal * 1e6, y * 1e6))
            return
        if self._phase == 'sweep':
            self._sweep(t, y, pw)
        elif self._phase == 'verify':
            if pw is not None:
                self._verify.append(pw)
            self._setpoint = self._goal
            if len(self._verify) < int(p['verify_samples']):
                return
            meas = float(np.mean(self._verify))
            miss_db = 10.0 * math.log10(math.exp(self._fit_lp0) / max(meas, 1e-300))
            if miss_db > p['verify_tolerance_db'] and self._refits < int(p['max_refits']):
                self._refits += 1
                self._log('peak missed by %.3f dB; local re-sweep' % miss_db)
                self._start_local(self._goal)
                return
            self.aligned_position_m = self._goal
            self.aligned_power_w = meas
            self.peak_t = t
            self._start_tracking(t)

    def _sweep(self, t, y, pw):
        p = self.p
        if pw is not None and pw > 0:
            self._samples.append((t, y, pw))
        self._setpoint = min(self._setpoint + self._sweep_speed * self.dt, self._sweep_end)
        if not self._samples:
            return
        arr = np.asarray(self._samples)
        pmax = arr[:, 2].max()
        imax = int(arr[:, 2].argmax())
        dropped = pw is not None and pw < pmax * 10 ** (-p['peak_drop_db'] / 10.0) and \
            imax < len(arr) - 1 and len(arr) >= int(p['peak_min_fit_samples'])
        at_end = self._setpoint >= self._sweep_end and \
            abs(y - self._sweep_end) < p['settle_tolerance_m'] * 4
        if not (dropped or at_end):
            return
        self._fit_and_go(arr, pmax, local=self._sweep_end != p['range_max_m'])

    def _fit_and_go(self, arr, pmax, local):
        p = self.p
        # pair each power with the displacement power_lag_s earlier (detector averaging)
        tt, yy, pp = arr[:, 0], arr[:, 1], arr[:, 2]
        x = np.interp(tt - p['power_lag_s'], tt, yy) if len(tt) > 1 else yy
        keep = pp >= pmax * 10 ** (-p['peak_fit_window_db'] / 10.0)
        if self.threshold_w is not None:
            keep &= pp > 3.0 * self.threshold_w
        fit = None
        if keep.sum() >= int(p['peak_min_fit_samples']) or (local and keep.sum() >= 2):
            curv = self.curvature_per_m2 if (local and keep.sum() < 5) else None
            fit = fit_log_paraboloid_groups(x[keep, None], pp[keep], ((0,),), curvature=curv)
        lo, hi = p['range_min_m'], p['range_max_m']
        tol = p['range_tolerance_m']
        x0 = None if fit is None else fit[0][0]
        if fit is None or x0 > hi + tol or x0 < lo - tol:
            if not self._first_sweep:
                self._widen(yy)
                return
            best = yy[int(pp.argmax())]
            where = '' if x0 is None else 'peak estimated at %.1f um, ' % (x0 * 1e6)
            if (x0 is not None and x0 > hi) or (
                    x0 is None and not local and best >= yy.max() - 1e-6):
                self._fault('slot outside the reachable range: power still rising at the end '
                            'of travel (%s%.1f..%.1f um reachable)'
                            % (where, lo * 1e6, hi * 1e6))
            elif (x0 is not None and x0 < lo) or (
                    x0 is None and not local and best <= yy.min() + 1e-6):
                self._fault('slot outside the reachable range: power falls from the start of '
                            'travel (%s%.1f..%.1f um reachable)'
                            % (where, lo * 1e6, hi * 1e6))
            else:
                self._fault('peak search failed: the %d samples over %.1f..%.1f um do not '
                            'show a peak' % (len(pp), yy.min() * 1e6, yy.max() * 1e6))
            return
        (x0,), (c,), lp0 = fit
        self.curvature_per_m2 = c
        self._fit_lp0 = lp0
        self._goal = min(max(x0, lo), hi)
        self._phase = 'goto_peak'
