# SPDX-License-Identifier: Apache-2.0
"""
Geometry and estimators of the 2-D alignment (pure numpy, SI units).

- :func:`capture_radius` and :func:`spiral_pitch`: how far apart the arms of the first-light
  spiral may be for a given mode radius.
- :class:`SpiralPath`: a straight transit to the centre of the reachable square, then an
  Archimedean spiral out to its corners, walked at a constant speed.
- :func:`fit_log_paraboloid`: weighted least squares of ``ln P`` on a circular paraboloid,
  the exact shape of the Gaussian mode overlap.
"""

import math

import numpy as np

LN10_OVER_10 = math.log(10.0) / 10.0   # dB -> natural log of a power ratio


def capture_radius(mode_radius_m, capture_db):
    """
    Return the offset (m) at which the coupling is ``capture_db`` (dB) below its peak.

    ``P / P_max = exp(-(d / w)^2)`` (gap term neglected: it only widens the mode, so this
    is the conservative side), hence ``d = w sqrt(capture_db ln(10) / 10)``.
    """
    return float(mode_radius_m) * math.sqrt(float(capture_db) * LN10_OVER_10)


def spiral_pitch(mode_radius_m, capture_db, chord_m):
    """
    Return the largest arm spacing (m) of a spiral that cannot pass light by.

    A target half-way between two arms is ``pitch / 2`` from each; the arm then runs within
    the capture radius ``r_c`` over a chord ``2 sqrt(r_c^2 - (pitch / 2)^2)``, which must
    hold ``chord_m`` (m): the readings needed to confirm first light, walked at the search
    speed. So ``pitch = 2 sqrt(r_c^2 - (chord / 2)^2)``.

    :param mode_radius_m: mode-field radius ``w`` (m).
    :param capture_db: smallest peak-to-threshold ratio (dB) the search must still catch.
    :param chord_m: path length (m) over which the power must stay above the threshold.
    """
    rc = capture_radius(mode_radius_m, capture_db)
    half = 0.5 * float(chord_m)
    if not rc > half:
        raise ValueError('capture radius %.3g m is not larger than half the confirm chord '
                         '%.3g m: lower the search speed or raise spiral_capture_db'
                         % (rc, half))
    return 2.0 * math.sqrt(rc * rc - half * half)


class SpiralPath:
    """
    Straight line from ``start`` to ``center``, then ``r = pitch theta / (2 pi)`` outwards.

    :param start: ``(x, y)`` where the walk begins (m).
    :param center: ``(x, y)`` centre of the spiral (m).
    :param pitch_m: distance between arms (m).
    :param r_max_m: the walk ends when the radius passes this (m).
    """

    def __init__(self, start, center, pitch_m, r_max_m):
        """Set the walk up at ``start``."""
        self.start = (float(start[0]), float(start[1]))
        self.center = (float(center[0]), float(center[1]))
        self.b = float(pitch_m) / (2.0 * math.pi)      # m per rad
        self.r_max = float(r_max_m)
        self.transit = math.hypot(self.center[0] - self.start[0],
                                  self.center[1] - self.start[1])
        self.s = 0.0
        self.theta = 0.0
        self.done = False

    def advance(self, ds_m):
        """Walk ``ds_m`` (m) further; return the new point ``(x, y)`` (m)."""
        self.s += float(ds_m)
        if self.s < self.transit:
            f = self.s / self.transit
            return (self.start[0] + f * (self.center[0] - self.start[0]),
                    self.start[1] + f * (self.center[1] - self.start[1]))
        ds = min(float(ds_m), self.s - self.transit)
        # arc length of r = b theta: ds = sqrt(r^2 + b^2) dtheta; sub-steps keep it exact
        n = max(1, int(math.ceil(ds / (0.25 * self.b))))
        for _ in range(n):
            self.theta += (ds / n) / math.hypot(self.b * self.theta, self.b)
        r = self.b * self.theta
        if r >= self.r_max:
            self.done = True
        return (self.center[0] + r * math.cos(self.theta),
                self.center[1] + r * math.sin(self.theta))

    def points(self, ds_m):
        """Return the whole walk sampled every ``ds_m`` (m) as an ``(n, 2)`` array (m)."""
        out = [self.start]
        while not self.done:
            out.append(self.advance(ds_m))
        return np.asarray(out)


def fit_log_paraboloid(x_m, y_m, p_w, weights=None, curvature=None):
    """
    Fit ``ln P = ln P0 - k ((x - x0)^2 + (y - y0)^2)``; return ``(x0, y0, k, ln P0)``.

    Weighted linear least squares in ``(1, x, y, x^2 + y^2)`` (coordinates in um about
    their mean, for conditioning). With ``curvature`` given (1/m^2) only ``ln P0``, ``x0``
    and ``y0`` are fitted (3 samples suffice, else 4). Returns ``None`` when the samples do
    not define a peak (too few, degenerate, or ``k <= 0``).

    :param x_m: sample positions along x (m).
    :param y_m: sample positions along y (m).
    :param p_w: sample powers (W), > 0.
    :param weights: ``1 / variance`` of each ``ln P`` (None: equal).
    :param curvature: known ``k`` (1/m^2) or None.
    """
    x = np.asarray(x_m, dtype=float)
    y = np.asarray(y_m, dtype=float)
    lp = np.log(np.asarray(p_w, dtype=float))
    w = np.ones_like(x) if weights is None else np.asarray(weights, dtype=float)
    if x.size < (3 if curvature else 4):
        return None
    xm, ym = x.mean(), y.mean()
    xs, ys = (x - xm) * 1e6, (y - ym) * 1e6
    r2 = xs * xs + ys * ys
    sw = np.sqrt(w)
    if curvature:
        k = float(curvature) * 1e-12                       # 1/um^2
        a = np.vstack([np.ones_like(xs), xs, ys]).T
        rhs = lp + k * r2
    else:
        a = np.vstack([np.ones_like(xs), xs, ys, -r2]).T
        rhs = lp
    coef, _, rank, _ = np.linalg.lstsq(a * sw[:, None], rhs * sw, rcond=None)
    if rank < a.shape[1]:
        return None
    if not curvature:
        k = float(coef[3])
        if not k > 0:
            return None
    x0, y0 = coef[1] / (2.0 * k), coef[2] / (2.0 * k)
    lp0 = coef[0] + k * (x0 * x0 + y0 * y0)
    return xm + x0 * 1e-6, ym + y0 * 1e-6, k * 1e12, float(lp0)
