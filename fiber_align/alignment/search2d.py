# SPDX-License-Identifier: Apache-2.0
"""
Geometry of the 2-D search, and the fit of ``ln P`` every machine peaks with (pure numpy, SI).

- :func:`capture_radius` and :func:`spiral_pitch`: how far apart the arms of the first-light
  spiral may be for a given mode radius.
- :class:`SpiralPath`: a straight transit to the centre of the reachable square, then an
  Archimedean spiral out to its corners, walked at a constant speed.
- :func:`fit_log_paraboloid_groups`: weighted least squares of ``ln P`` on circular
  paraboloids of groups of axes, the exact shape of Gaussian mode overlaps: the 1-D
  sweep's parabola (one group of one axis), the 2-D cross's paraboloid (x and y), the
  station's two sides, the array's channels.
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


def fit_log_paraboloid_groups(pos_m, p_w, groups, weights=None, curvature=None):
    """
    Fit ``ln P = ln P0 - sum_g k_g |r_g - c_g|^2``: a circular paraboloid per group of axes.

    Weighted linear least squares in ``(1, coordinates..., |r_g|^2...)`` (coordinates in um
    about their mean, for conditioning): the exact shape of Gaussian mode overlaps (one
    group of one axis: the 1-D sweep's; of x and y: the 2-D cross's; the input and the
    output side: the station's).

    :param pos_m: ``(n, d)`` sample positions (m).
    :param p_w: sample powers (W), > 0.
    :param groups: the axes (indices) of each circular paraboloid, e.g. ``((0, 1),)``.
    :param weights: ``1 / variance`` of each ``ln P`` (None: equal).
    :param curvature: a known ``k`` (1/m^2) for every group, or None to fit one per group.
    :returns: ``(vertex (d,) m, [k_g (1/m^2)], ln P0)``, or None when the samples do not
        define a peak (too few, degenerate, a curvature <= 0).
    """
    x = np.asarray(pos_m, dtype=float)
    lp = np.log(np.asarray(p_w, dtype=float))
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=float)
    d = x.shape[1]
    if len(x) < 1 + d + (0 if curvature else len(groups)):
        return None
    mean = x.mean(axis=0)
    xs = (x - mean) * 1e6                                     # um, for conditioning
    r = [sum(xs[:, a] * xs[:, a] for a in g) for g in groups]
    ones = np.ones(len(x))
    if curvature:
        k = float(curvature) * 1e-12                          # 1/um^2
        a = np.column_stack([ones, xs])
        rhs = lp + k * sum(r)
    else:
        a = np.column_stack([ones, xs] + [-q for q in r])
        rhs = lp
    sw = np.sqrt(w)
    coef, _, rank, _ = np.linalg.lstsq(a * sw[:, None], rhs * sw, rcond=None)
    if rank < a.shape[1]:
        return None
    ks = [k] * len(groups) if curvature else [float(c) for c in coef[1 + d:]]
    if not all(q > 0 for q in ks):
        return None
    kk = np.zeros(d)
    for g, q in zip(groups, ks):
        kk[list(g)] = q
    v = coef[1:1 + d] / (2.0 * kk)
    lp0 = coef[0] + float(np.sum(kk * v * v))
    return mean + v * 1e-6, [q * 1e12 for q in ks], float(lp0)
