# SPDX-License-Identifier: Apache-2.0
"""
PEAKING of the coupled station: the joint fit of both sides (the station's method).

:class:`JointPeakMixin` is mixed into :class:`~fiber_align.alignment.station.Station`; it
expects ``p`` (parameters), ``lo`` / ``hi`` (the four axes' ranges, m), ``floor``,
``curvature_prior`` (1/m^2), ``iterations``, ``_history``, ``_t``, ``_fault``, ``_log``,
``_start_tracking`` and ``_false_light`` (nothing lit around first light: resume the
search); the visits, weights and the verifying reading are the shared
:class:`~fiber_align.alignment.visit.PointPeaking`.

One iteration reads ``1 + 4`` settled points: the centre and one point ``h`` away along
each of the four axes, on the ``+`` side in odd iterations and the ``-`` side in even ones.
``ln P`` of the two Gaussian overlaps is exactly a separable paraboloid everywhere
(:func:`~fiber_align.alignment.search2d.fit_log_paraboloid_groups` of the two ``SIDES``),
so the fit pools the readings of the last ``fit_history_patterns`` patterns whose centres
lie near the present one: with both sides of every axis it fits a curvature per side;
otherwise (a pattern alone: 5 unknowns, 5 points), or when that vertex lies outside the
pattern (an extrapolation) or a curvature far from the prior, it fits with the curvature
prior. Near first light the steps away from the peak read dark: then the mirror points of
those axes (``-h`` where ``+h`` was dark) complete the pattern before the fit. The centre
moves to the vertex; converged when the vertex is within ``converge_tolerance_m`` of the
centre; a reading at the vertex then verifies the fit's peak (a miss runs another pattern,
pooled with this one, so with both sides of every axis).

Both sides move in every iteration: each axis costs one point, the centre reading is
shared by all four, where the serial 2-D method reads two points an axis and a centre per
side. SI units.
"""

import numpy as np

from fiber_align.alignment import search2d as s2
from fiber_align.alignment.visit import PointPeaking

AXES4 = ('x_in', 'y_in', 'x_out', 'y_out')
#: the two circular paraboloids of ``ln P``: the input side's axes, the output side's
SIDES = ((0, 1), (2, 3))


class JointPeakMixin(PointPeaking):
    """Visit points settled in four axes, fit both sides together, iterate to convergence."""

    #: a vertex this close, even with the prior curvature, is off by at most the step
    #: times the prior's error; the reading at the vertex checks the fit's peak (a wrong
    #: curvature shows there) and a miss pools another pattern
    PRIOR_CONVERGES = True

    def _start_pattern(self, center, radius):
        self._phase = 'pattern'
        self._center = np.clip(np.asarray(center, float), self.lo, self.hi)
        self._radius = float(radius)
        self._sign = 1.0 if self.iterations % 2 == 0 else -1.0
        self._completed = False
        pts = [self._center] + [self._center + self._sign * self._radius * e
                                for e in np.eye(4)]
        self._visit(pts, self._fit_joint)

    def _complete(self, rows, ok_last):
        """Read the mirror points of the axes whose point read dark; then fit all."""
        self._phase = 'complete'
        self._completed = True
        self._partial = rows
        dark = [a for a in range(4) if not ok_last[1 + a]]
        pts = [self._center - self._sign * self._radius * np.eye(4)[a] for a in dark]
        self._visit(pts, lambda more: self._fit_joint(np.vstack([self._partial, more]),
                                                      count=False))

    def _fit_joint(self, rows, count=True):
        p = self.p
        if count:
            self.iterations += 1
            self._history.append((self._center, rows))
        else:
            self._history[-1] = (self._center, rows)
        self._history = self._history[-int(p['fit_history_patterns']):]
        # the pooled fit takes the patterns near this one only: far ones (before a long
        # step) would make the curvature, and so the vertex, an extrapolation
        near = [r for c, r in self._history
                if np.linalg.norm(c - self._center) <= 2.0 * p['pattern_radius_max_m']]
        data = np.vstack(near)
        ok, w = self._weights(data[:, 4])
        fit, prior = None, False
        if ok.sum() >= 7:
            fit = s2.fit_log_paraboloid_groups(data[ok, :4], data[ok, 4], SIDES, w[ok])
            r = p['curvature_ratio_max']
            if fit is not None and (
                    not all(self.curvature_prior / r < k < self.curvature_prior * r
                            for k in fit[1])
                    or np.linalg.norm(fit[0] - self._center) > self._radius):
                fit = None
        ok_last = self._weights(rows[:, 4])[0]
        if fit is None and not self._completed and ok_last[0] and not ok_last[1:5].all():
            return self._complete(rows, ok_last)
        if fit is None and ok.sum() >= 5:
            prior = True
            fit = s2.fit_log_paraboloid_groups(data[ok, :4], data[ok, 4], SIDES, w[ok],
                                               curvature=self.curvature_prior)
        if fit is None:
            return self._no_fit(rows, ok.sum(), search_on=True)
        if self._move_to(fit[0], fit, prior, ok.sum()):
            self.curvatures_per_m2 = tuple(fit[1])
            self._verify_at(fit[0])
