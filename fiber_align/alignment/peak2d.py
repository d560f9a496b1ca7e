# SPDX-License-Identifier: Apache-2.0
"""
PEAKING of the 2-D sequencer: settled readings at a pattern of points, paraboloid fit.

:class:`PeakFitMixin` holds the part of :class:`~fiber_align.alignment.sequencer2d.
Sequencer2D` that visits points and fits them; the baseline
:class:`~fiber_align.alignment.hillclimb2d.HillClimb2D` reuses the visiting. It expects
from the class it is mixed into: ``p`` (parameters), ``lo`` / ``hi`` (the square, m),
``floor``, ``curvature_prior``, ``iterations``, ``_t``, ``_fault``, ``_log`` and
``_start_tracking``.

One iteration reads a cross of five points (centre and +-``h`` along x and y), each after
the tip settled within ``settle_tolerance_m`` in both axes for ``settle_samples`` readings,
averaging ``point_samples`` readings of position (measured, m) and power (W). The fit is
weighted by the noise of ``ln P`` (floor noise over power, plus the relative intensity
noise); readings within ``fit_min_snr`` of the floor are left out. SI units throughout.
"""

import math

import numpy as np

from fiber_align.alignment import search2d as s2

AXES = ('x', 'y')


def dbm(p_w):
    """Return ``p_w`` (W) in dBm for messages; ``nan`` for ``None``."""
    if p_w is None:
        return float('nan')
    return 10.0 * math.log10(max(p_w, 1e-15) / 1e-3)


class PeakFitMixin:
    """Visit points settled, fit ``ln P`` with a circular paraboloid, iterate to convergence."""

    def _visit(self, points, done):
        """Read each point of ``points`` (m) settled; then call ``done(list of rows)``."""
        self._queue = [np.minimum(np.maximum(np.asarray(q, float), self.lo), self.hi)
                       for q in points]
        self._rows = []
        self._on_done = done
        self._next_point()

    def _next_point(self):
        self._goal = self._queue.pop(0)
        self._goal_t = None
        self._settle = 0
        self._acc = []

    def _do_visit(self, t, pos, pw):
        p = self.p
        self.sp = self._goal.copy()
        if self._goal_t is None:
            self._goal_t = t
            return
        if len(self._acc) == 0:
            near = np.all(np.abs(pos - self._goal) < p['settle_tolerance_m'])
            self._settle = self._settle + 1 if near else 0
            late = t - self._goal_t > p['settle_timeout_s']
            if self._settle < int(p['settle_samples']) and not late:
                return
            if late and not np.all(np.abs(pos - self._goal) < 10 * p['settle_tolerance_m']):
                self._fault('actuator does not settle at (%.2f, %.2f) um (at %.2f, %.2f um)'
                            % tuple(np.concatenate([self._goal, pos]) * 1e6))
                return
        if pw is None:
            return
        self._acc.append((pos[0], pos[1], pw))
        if len(self._acc) < int(p['point_samples']):
            return
        self._rows.append(np.mean(np.asarray(self._acc), axis=0))
        if self._queue:
            self._next_point()
        else:
            self._on_done(np.asarray(self._rows))

    def _start_pattern(self, center, radius):
        self._phase = 'pattern'
        self._center = np.minimum(np.maximum(np.asarray(center, float), self.lo), self.hi)
        self._radius = float(radius)
        c, h = self._center, self._radius
        pts = [c, c + (h, 0.0), c + (0.0, h), c - (h, 0.0), c - (0.0, h)]
        self._visit(pts, self._fit_pattern)

    def _weights(self, pw):
        """Return the validity mask and the weights (1 / variance of ln P) of readings (W)."""
        p = self.p
        sigma = self.floor[1] if self.floor else p['min_threshold_w']
        n = int(p['point_samples'])
        rin = p['power_noise_db'] * s2.LN10_OVER_10
        ok = pw > p['fit_min_snr'] * max(sigma, 1e-300)
        var = ((sigma / np.maximum(pw, 1e-300)) ** 2 + rin * rin) / n
        return ok, 1.0 / var

    def _fit_pattern(self, rows):
        p = self.p
        self.iterations += 1
        ok, w = self._weights(rows[:, 2])
        fit, prior = None, False
        if ok.sum() >= 4:
            fit = s2.fit_log_paraboloid(rows[ok, 0], rows[ok, 1], rows[ok, 2], w[ok])
            r = p['curvature_ratio_max']
            # far outside the cross the vertex is an extrapolation whose error scales with
            # the curvature's: there the prior (from the mode radius) is the better guess
            if fit is not None and (not (self.curvature_prior / r < fit[2]
                                         < self.curvature_prior * r) or np.hypot(
                    fit[0] - self._center[0], fit[1] - self._center[1]) > 2 * self._radius):
                fit = None
        if fit is None and ok.sum() >= 3:
            prior = True
            fit = s2.fit_log_paraboloid(rows[ok, 0], rows[ok, 1], rows[ok, 2], w[ok],
                                        curvature=self.curvature_prior)
        if fit is None:
            if ok.sum() == 0:
                self._fault('light lost while peaking: no reading above %.1f dBm around '
                            '(%.1f, %.1f) um' % (dbm(p['fit_min_snr'] * self.floor[1]),
                                                 *(self._center * 1e6)))
                return
            best = rows[int(np.argmax(rows[:, 2])), :2]
            return self._iterate(best, self._radius)
        vertex = np.array(fit[:2])
        out = (vertex < self.lo - p['range_tolerance_m']) | \
            (vertex > self.hi + p['range_tolerance_m'])
        at_edge = (np.abs(self._center - self.lo) < p['settle_tolerance_m']) | \
            (np.abs(self._center - self.hi) < p['settle_tolerance_m'])
        bad = [a for a in range(2) if out[a] and at_edge[a]]
        if bad and ok.sum() >= 4:
            self._fault('target out of reach in %s: peak estimated at (%.1f, %.1f) um, '
                        'reachable x %.1f..%.1f um, y %.1f..%.1f um'
                        % (' and '.join(AXES[a] for a in bad), *(vertex * 1e6),
                           self.lo[0] * 1e6, self.hi[0] * 1e6, self.lo[1] * 1e6,
                           self.hi[1] * 1e6))
            return
        step = vertex - self._center
        dist = float(np.hypot(*step))
        self._log('cross %d at (%.2f, %.2f) um, radius %.2f um, %d lit: vertex (%.2f, %.2f) um'
                  '%s' % (self.iterations, *(self._center * 1e6), self._radius * 1e6,
                          ok.sum(), *(vertex * 1e6), ' (curvature prior)' if prior else ''))
        if dist > p['max_step_m']:
            step *= p['max_step_m'] / dist
        self._fit = fit
        if dist < p['converge_tolerance_m'] and not prior:
            self.curvature_per_m2 = fit[2]
            self._phase = 'verify'
            self._visit([vertex], self._verify)
            return
        h = min(max(p['pattern_radius_gain'] * dist, p['pattern_radius_min_m']),
                p['pattern_radius_max_m'])
        self._iterate(self._center + step, h)

    def _iterate(self, center, radius):
        if self.iterations >= int(self.p['max_iterations']):
            self._fault('peak search did not converge in %d iterations (last cross at '
                        '(%.2f, %.2f) um)' % (self.iterations, *(self._center * 1e6)))
            return
        self._start_pattern(center, radius)

    def _verify(self, rows):
        p = self.p
        meas = float(rows[0, 2])
        miss_db = 10.0 * math.log10(math.exp(self._fit[3]) / max(meas, 1e-300))
        if miss_db > p['verify_tolerance_db'] and \
                self.iterations < int(p['max_iterations']):
            self._log('reading %.3f dB below the fitted peak; another cross' % miss_db)
            self._start_pattern(rows[0, :2], p['pattern_radius_min_m'])
            return
        self.aligned = self._goal.copy()
        self.aligned_power_w = meas
        self._start_tracking(t=self._t)
