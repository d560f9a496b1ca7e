# SPDX-License-Identifier: Apache-2.0
"""
TRACKING, one law for every sequencer: dither extremum seeking over ``n`` axes.

The setpoints are the estimate ``x_hat`` plus a dither: a sine of ``amplitude_m`` on a lone
axis, a circle of that radius on a pair of axes (cos on the first, sin on the second), each
at its own frequency. One regression of ``ln P`` on the measured displacements
(:class:`JointDemodulator`) gives the gradient in every axis at once (phase-free: the
loop's lag at the dither frequency does not bias it; a circle at another frequency does not
leak into it); each axis' estimate moves at ``bandwidth * g / (2 k)`` with the fitted
curvature ``k`` of that axis, an integral action whose loop bandwidth is
``tracking_bandwidth_rad_s`` whatever the fiber. A step is limited to
``5 * bandwidth * dt * amplitude`` (its norm).

The lost-power rule (:class:`LossWatch`): a reading more than ``track_loss_db`` below the
aligned power holds the estimate (the dither goes on); one that stays there longer than
``track_loss_timeout_s`` is a FAULT. SI units: s, m, W; dB only for ratios.
"""

import math

import numpy as np

from fiber_align.alignment.states import dbm


class JointDemodulator:
    """
    Gradient of ``ln P`` (1/m) in ``n`` coordinates, dithered at distinct frequencies.

    ``ln P`` regressed on the measured displacements about their running means (window
    ``time_s``), all ``n`` at once; each reading paired with the positions ``lag_s`` (s)
    earlier (the detector's averaging delay; 0: the same period's). It runs on every
    control period of TRACKING, on a handful of axes: plain floats and lists, not numpy
    (whose per-call cost on arrays of three was most of an update: 82 us, now
    ``bench/bench_tracking.py``).
    """

    def __init__(self, n, time_s, lag_s=0.0):
        """Start empty."""
        self.n = int(n)
        self.time_s = float(time_s)
        self.lag_s = float(lag_s)
        self.reset()

    def reset(self):
        """Forget the statistics."""
        n = self.n
        self.count = 0
        self.m = [0.0] * (n + 1)
        self.cov = [[0.0] * n for _ in range(n)]
        self.cross = [0.0] * n
        self.prev = None

    def update(self, dt_s, pos_m, ln_p):
        """Add one reading: positions (m) and ``ln P`` (power in W)."""
        try:
            pos = [float(x) for x in pos_m]
        except TypeError:               # one axis given as a number
            pos = [float(pos_m)]
        prev = self.prev
        if prev is not None and dt_s > 0 and self.lag_s > 0:
            f = min(1.0, self.lag_s / dt_s)
            lagged = [x - f * (x - x0) for x, x0 in zip(pos, prev)]
        else:
            lagged = pos
        self.prev = pos
        ln_p = float(ln_p)
        if self.count == 0:
            self.m = lagged + [ln_p]
            self.count = 1
            return
        a = min(1.0, dt_s / self.time_s) if dt_s > 0 else 1.0
        b = 1.0 - a
        m = self.m
        d = [x - mx for x, mx in zip(lagged, m)]
        dp = ln_p - m[-1]
        self.m = [mx + a * dx for mx, dx in zip(m, d)] + [m[-1] + a * dp]
        for row, di in zip(self.cov, d):
            adi = a * di
            for j, dj in enumerate(d):
                row[j] = b * (row[j] + adi * dj)
        self.cross = [b * (c + a * di * dp) for c, di in zip(self.cross, d)]
        self.count += 1

    def gradient(self, min_var_m2):
        """Return ``d ln P / d pos`` (1/m); None while a variance < ``min_var_m2`` (m^2)."""
        n, cov = self.n, self.cov
        var = [cov[i][i] for i in range(n)]
        if any(v < min_var_m2 for v in var):
            return None
        det, x = _solve(cov, self.cross)
        # the correlation matrix's determinant, det(cov) / prod(var): 1 for separable
        # dithers, 0 for dependent ones
        if not det / math.prod(var) > 0.25:
            return None
        return np.array(x)


def _solve(a, b):
    """
    Solve ``a x = b`` (lists of floats; Gaussian elimination, partial pivoting).

    Return ``(det(a), x)``; ``(0.0, None)`` for a singular ``a``. ``a`` is not changed.
    """
    n = len(b)
    rows = [list(r) + [v] for r, v in zip(a, b)]
    det = 1.0
    for k in range(n):
        p = max(range(k, n), key=lambda i: abs(rows[i][k]))
        if not rows[p][k]:
            return 0.0, None
        if p != k:
            rows[k], rows[p] = rows[p], rows[k]
            det = -det
        rk = rows[k]
        piv = rk[k]
        det *= piv
        for i in range(k + 1, n):
            ri = rows[i]
            f = ri[k] / piv
            for j in range(k, n + 1):
                ri[j] -= f * rk[j]
    x = [0.0] * n
    for i in range(n - 1, -1, -1):
        ri = rows[i]
        x[i] = (ri[n] - sum(ri[j] * x[j] for j in range(i + 1, n))) / ri[i]
    return det, x


class LossWatch:
    """The lost-power rule of TRACKING (module docstring; W, dB, s)."""

    def __init__(self, aligned_w, loss_db, timeout_s):
        """Watch for readings ``loss_db`` below ``aligned_w`` for ``timeout_s``."""
        self.aligned_w = float(aligned_w)
        self.loss_db = float(loss_db)
        self.low_w = self.aligned_w * 10 ** (-self.loss_db / 10.0)
        self.timeout_s = float(timeout_s)
        self.since = None
        #: why TRACKING ends in FAULT ('' while it does not)
        self.fault = ''

    def lost(self, t, pw):
        """Return True while the reading ``pw`` (W, at ``t`` s) is far below the aligned."""
        if pw is None:
            return False
        if pw >= self.low_w:
            self.since = None
            return False
        if self.since is None:
            self.since = t
        elif t - self.since > self.timeout_s:
            self.fault = ('power lost while tracking: %.1f dBm, more than %.0f dB below the '
                          'aligned %.1f dBm (broken fiber or chip, source off or target '
                          'moved away)' % (dbm(pw), self.loss_db, dbm(self.aligned_w)))
        return True


class Tracker:
    """
    The dither tracker of one TRACKING run (module docstring).

    :param center: the aligned point the estimate starts at (m, one per axis).
    :param curvatures: ``k`` of ``ln P`` per axis (1/m^2; one value: every axis).
    :param dithers: ``(frequency_hz, axes)`` pairs of the dithers of ``amplitude_m`` (m):
        one axis a sine, two a circle; ``t0``: TRACKING's start (s).
    :param p: the sequencer's parameters (``tracking_*``, ``gradient_time_s``, ``track_*``).
    :param lo: limits of the estimate (m), with ``hi``; ``aligned_w``: the aligned power
        (W); ``lag_s``: the detector's delay (s) the demodulator undoes.
    """

    def __init__(self, center, curvatures, amplitude_m, dithers, t0, p, lo, hi, aligned_w,
                 lag_s=0.0):
        """Start at ``center`` with an empty demodulator."""
        self.xhat = np.array(center, dtype=float).reshape(-1)
        n = self.xhat.size
        self.k = np.broadcast_to(np.asarray(curvatures, dtype=float), (n,))
        self.amplitude_m = float(amplitude_m)
        self.dithers = tuple((float(f), tuple(ax)) for f, ax in dithers)
        self.t0 = float(t0)
        self.bandwidth = float(p['tracking_bandwidth_rad_s'])
        self.time_s = float(p['gradient_time_s'])
        self.lo, self.hi = lo, hi
        self.demod = JointDemodulator(n, self.time_s, lag_s)
        self.loss = LossWatch(aligned_w, p['track_loss_db'], p['track_loss_timeout_s'])

    def offset(self, t):
        """Return the dither at ``t`` (s): one value per axis (m)."""
        out = np.zeros(self.xhat.size)
        for f, ax in self.dithers:
            ph = 2.0 * math.pi * f * (t - self.t0)
            if len(ax) == 1:
                out[ax[0]] = self.amplitude_m * math.sin(ph)
            else:
                out[ax[0]] = self.amplitude_m * math.cos(ph)
                out[ax[1]] = self.amplitude_m * math.sin(ph)
        return out

    def step(self, t, dt, pos, pw):
        """
        Take the readings of one period; return the setpoints (m), or None on a FAULT.

        :param t: time (s); ``dt``: since the last period (s).
        :param pos: measured positions (m); ``pw``: power reading (W) or None.
        """
        lost = self.loss.lost(t, pw)
        if self.loss.fault:
            return None
        a = self.amplitude_m
        if not lost and pw is not None and pw > 0:
            self.demod.update(dt, pos, math.log(pw))
            g = self.demod.gradient(0.1 * a * a)
            if g is not None and t - self.t0 > self.time_s:
                step = self.bandwidth * dt / (2.0 * self.k) * g
                lim = self.bandwidth * dt * 5 * a
                n = float(np.linalg.norm(step))
                self.xhat = self.xhat + step * (min(1.0, lim / n) if n > 0 else 1.0)
        self.xhat = np.minimum(np.maximum(self.xhat, self.lo), self.hi)
        return self.xhat + self.offset(t)
