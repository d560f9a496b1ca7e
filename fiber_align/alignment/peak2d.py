# SPDX-License-Identifier: Apache-2.0
"""
PEAKING of the 2-D sequencer: settled readings at a pattern of points, paraboloid fit.

:class:`PeakFitMixin` holds the part of :class:`~fiber_align.alignment.sequencer2d.
Sequencer2D` that fits; the visits, weights and verification are the shared
:class:`~fiber_align.alignment.visit.PointPeaking` (the baseline
:class:`~fiber_align.alignment.hillclimb2d.HillClimb2D` reuses the visiting). It expects
from the class it is mixed into: ``p`` (parameters), ``lo`` / ``hi`` (the square, m),
``floor``, ``curvature_prior``, ``iterations``, ``_t``, ``_fault``, ``_log`` and
``_start_tracking``.

One iteration reads a cross of five points (centre and +-``h`` along x and y), each
settled (:class:`~fiber_align.alignment.visit.Visit`). The fit is weighted by the noise of
``ln P`` (floor noise over power, plus the relative intensity noise); readings within
``fit_min_snr`` of the floor are left out. SI units throughout.
"""

import numpy as np

from fiber_align.alignment import search2d as s2
from fiber_align.alignment.visit import PointPeaking

AXES = ('x', 'y')


class PeakFitMixin(PointPeaking):
    """Visit points settled, fit ``ln P`` with a circular paraboloid, iterate to convergence."""

    PATTERN = 'cross'
    #: True: nothing lit around the first-light point resumes the search (a noise spike
    #: ended it: the machine's ``_false_light``); False: the host decides (its ``_fault``)
    RESUMES_SEARCH = False
    PRIOR_CONVERGES = False
    AXIS_NAMES = AXES

    def _start_pattern(self, center, radius):
        self._phase = 'pattern'
        self._center = np.minimum(np.maximum(np.asarray(center, float), self.lo), self.hi)
        self._radius = float(radius)
        c, h = self._center, self._radius
        pts = [c, c + (h, 0.0), c + (0.0, h), c - (h, 0.0), c - (0.0, h)]
        self._visit(pts, self._fit_pattern)

    def _fit_pattern(self, rows):
        p = self.p
        self.iterations += 1
        ok, w = self._weights(rows[:, 2])
        fit, prior = None, False
        if ok.sum() >= 4:
            fit = s2.fit_log_paraboloid_groups(rows[ok, :2], rows[ok, 2], ((0, 1),), w[ok])
            r = p['curvature_ratio_max']
            # far outside the cross the vertex is an extrapolation whose error scales with
            # the curvature's: there the prior (from the mode radius) is the better guess
            if fit is not None and (not (self.curvature_prior / r < fit[1][0]
                                         < self.curvature_prior * r) or np.hypot(
                    *(fit[0] - self._center)) > 2 * self._radius):
                fit = None
        if fit is None and ok.sum() >= 3:
            prior = True
            fit = s2.fit_log_paraboloid_groups(rows[ok, :2], rows[ok, 2], ((0, 1),), w[ok],
                                               curvature=self.curvature_prior)
        if fit is None:
            return self._no_fit(rows, ok.sum(), search_on=self.RESUMES_SEARCH)
        if self._move_to(fit[0], fit, prior, ok.sum(), reach=ok.sum() >= 4):
            self.curvature_per_m2 = fit[1][0]
            self._verify_at(fit[0])
