# SPDX-License-Identifier: Apache-2.0
"""
The settled visit of a point set, and what the point-pattern peak fits share.

:class:`Visit` reads each point of a set in turn (any number of axes): the setpoints go to
the point; once every axis is within ``settle_tolerance_m`` of it for ``settle_samples``
readings in a row (or ``settle_timeout_s`` passed, within ten times the tolerance) it
averages ``point_samples`` readings of the measured position (m) and the power (W); after
the last point it hands the rows ``(position..., power)`` to its ``done`` callback.

:class:`PointPeaking`: what the 2-D fit (:class:`~fiber_align.alignment.peak2d.
PeakFitMixin`) and the station's (:class:`~fiber_align.alignment.station_peak.
JointPeakMixin`) share: visits, weights of ``ln P``, the verifying reading at the vertex,
the next pattern. It expects ``p``, ``lo`` / ``hi`` (m), ``sp``, ``floor``, ``iterations``,
``_t``, ``_fault``, ``_log``, ``_start_tracking`` and ``_start_pattern``. SI units.
"""

import math

import numpy as np

from fiber_align.alignment.search2d import LN10_OVER_10
from fiber_align.alignment.states import dbm, um


class Visit:
    """
    Read ``points`` (m) one after another, each once settled (module docstring).

    :param done: called with the rows (an array ``(points, axes + 1)``) after the last.
    :param lo: lower limits the points are clipped to (m); ``hi``: upper.
    :param p: the sequencer's parameters (``settle_*``, ``point_samples``).
    """

    def __init__(self, points, done, lo, hi, p):
        """Start at the first point."""
        self.points = [np.minimum(np.maximum(np.asarray(q, float), lo), hi) for q in points]
        self.queue = list(self.points)
        self.rows = []
        self.done = done
        self.p = p
        self._next()

    def _next(self):
        self.goal = self.queue.pop(0)
        self.goal_t = None
        self.settle = 0
        self.acc = []

    def step(self, t, pos, pw):
        """Take one period's readings (s, m, W); return '' or why it faults (no settling)."""
        p = self.p
        if self.goal_t is None:
            self.goal_t = t
            return ''
        if not self.acc:
            near = np.all(np.abs(pos - self.goal) < p['settle_tolerance_m'])
            self.settle = self.settle + 1 if near else 0
            late = t - self.goal_t > p['settle_timeout_s']
            if self.settle < int(p['settle_samples']) and not late:
                return ''
            if late and not np.all(np.abs(pos - self.goal) < 10 * p['settle_tolerance_m']):
                return 'actuator does not settle at %s (at %s)' % (um(self.goal), um(pos))
        if pw is None:
            return ''
        self.acc.append(np.append(pos, pw))
        if len(self.acc) < int(p['point_samples']):
            return ''
        self.rows.append(np.mean(np.asarray(self.acc), axis=0))
        if self.queue:
            self._next()
        else:
            self.done(np.asarray(self.rows))
        return ''


class PointPeaking:
    """Visits, weights, verification and the iteration bound of a pattern fit."""

    #: what one iteration's point set is called in the events
    PATTERN = 'pattern'
    #: True: a fit with the curvature prior may end the iterations (its vertex is checked
    #: by the reading there); False: only a fit of its own curvature does
    PRIOR_CONVERGES = True

    def _visit(self, points, done):
        """Read each point of ``points`` (m) settled; then call ``done(rows)``."""
        self._visiting = Visit(points, done, self.lo, self.hi, self.p)

    def _do_visit(self, t, pos, pw):
        self.sp = self._visiting.goal.copy()
        why = self._visiting.step(t, pos, pw)
        if why:
            self._fault(why)

    def _weights(self, pw):
        """Return the validity mask and the weights (1 / variance of ln P) of readings (W)."""
        p = self.p
        sigma = self.floor[1] if self.floor else p['min_threshold_w']
        rin = p['power_noise_db'] * LN10_OVER_10
        ok = pw > p['fit_min_snr'] * max(sigma, 1e-300)
        var = ((sigma / np.maximum(pw, 1e-300)) ** 2 + rin * rin) / int(p['point_samples'])
        return ok, 1.0 / var

    def _no_fit(self, rows, lit, search_on=False):
        """
        No fit of a pattern's ``rows``: the next pattern around its brightest reading.

        None of them lit (``lit`` 0): the light is lost (FAULT), or, at the first pattern
        with ``search_on``, a noise spike ended the search there: it walks on.
        """
        n = len(self.lo)
        if lit == 0 and search_on and self.iterations == 1:
            return self._false_light()
        if lit == 0:
            return self._fault('light lost while peaking: no reading above %.1f dBm around %s'
                               % (dbm(self.p['fit_min_snr'] * self.floor[1]), um(self._center)))
        self._iterate(rows[int(np.argmax(rows[:, n])), :n], self._radius)

    def _move_to(self, vertex, fit, prior, lit, reach=True):
        """
        Move the pattern to the fit's ``vertex`` (m); return True when it converged there.

        FAULT (``reach``: the fit can tell) when the vertex lies more than
        ``range_tolerance_m`` beyond the range on an axis where the pattern is at its edge;
        a step longer than ``max_step_m`` is cut to it; converged (the caller verifies the
        vertex) when the step is within ``converge_tolerance_m``, else the next pattern.
        """
        p = self.p
        names = self.AXIS_NAMES
        out = (vertex < self.lo - p['range_tolerance_m']) | \
            (vertex > self.hi + p['range_tolerance_m'])
        at_edge = (np.abs(self._center - self.lo) < p['settle_tolerance_m']) | \
            (np.abs(self._center - self.hi) < p['settle_tolerance_m'])
        bad = [a for a in range(len(vertex)) if out[a] and at_edge[a]]
        if bad and reach:
            self._fault('target out of reach in %s: peak estimated at %s, reachable %s'
                        % (' and '.join(names[a] for a in bad), um(vertex), ', '.join(
                            '%s %.1f..%.1f um' % (names[a], self.lo[a] * 1e6, self.hi[a] * 1e6)
                            for a in bad)))
            return False
        step = vertex - self._center
        dist = float(np.linalg.norm(step))
        self._log('%s %d at %s, radius %.2f um, %d lit: vertex %s%s'
                  % (self.PATTERN, self.iterations, um(self._center), self._radius * 1e6, lit,
                     um(vertex), ' (curvature prior)' if prior else ''))
        if dist > p['max_step_m']:
            step *= p['max_step_m'] / dist
        self._fit = fit
        if dist < p['converge_tolerance_m'] and (self.PRIOR_CONVERGES or not prior):
            return True
        self._iterate(self._center + step, dist=dist)
        return False

    def _iterate(self, center, radius=None, dist=0.0):
        """Next pattern at ``center`` (m): of ``radius``, or one after a step ``dist`` (m)."""
        p = self.p
        if self.iterations >= int(p['max_iterations']):
            self._fault('peak search did not converge in %d iterations (last %s at %s)'
                        % (self.iterations, self.PATTERN, um(self._center)))
            return
        if radius is None:
            radius = min(max(p['pattern_radius_gain'] * dist, p['pattern_radius_min_m']),
                         p['pattern_radius_max_m'])
        self._start_pattern(center, radius)

    def _verify_at(self, vertex):
        """Read the vertex (m) settled: :meth:`_verify` checks the fit's peak there."""
        self._phase = 'verify'
        self._visit([vertex], self._verify)

    def _verify(self, rows):
        """Judge the reading at the vertex: TRACKING, or another pattern when it misses the fit."""
        p = self.p
        n = len(self.lo)
        meas = float(rows[0, n])
        miss_db = 10.0 * math.log10(math.exp(self._fit[-1]) / max(meas, 1e-300))
        if miss_db > p['verify_tolerance_db'] and self.iterations < int(p['max_iterations']):
            self._log('reading %.3f dB below the fitted peak; another %s'
                      % (miss_db, self.PATTERN))
            self._start_pattern(rows[0, :n], p['pattern_radius_min_m'])
            return
        self.aligned = self._visiting.goal.copy()
        self.aligned_power_w = meas
        self._start_tracking(self._t)
