# SPDX-License-Identifier: Apache-2.0
"""
Resonance suppression by input shaping of the reference (beyond the paper).

A shaper is a short FIR filter with non-negative taps that sum to 1 (so it keeps the
final value and never overshoots a step). Its zeros sit on the poles of the bending mode
sampled at the control period (exact ZOH discretisation), so a shaped reference passed
through an exact inverse of the static nonlinearity moves the mode without leaving
residual vibration, at the sample instants and between them (the mode's two states are
both at rest after the last tap). ``zv`` cancels the poles once (shortest); ``zvd``
cancels them twice (the shaper convolved with itself), which makes the cancellation
robust to an error in the natural frequency at the price of twice the delay.
"""

import cmath
import math

import numpy as np

KINDS = ('none', 'zv', 'zvd')


def sampled_pole(omega_n, zeta, period_s):
    """Return the z-plane pole ``exp((-zeta wn + j wd) T)`` of the mode (rad/s, s)."""
    wd = omega_n * math.sqrt(1.0 - zeta * zeta)
    return cmath.exp(complex(-zeta * omega_n, wd) * period_s)


def zv_taps(omega_n, zeta, period_s, max_len=1000):
    """
    Return the shortest non-negative taps ``h_0, 0.., h_{n-1}, h_n`` with a zero at the pole.

    Searches n = 2, 3, ... for taps at samples {0, n - 1, n} solving ``sum h = 1`` and
    ``sum h_i p^-i = 0`` (``p`` the sampled pole) with all ``h >= 0``.

    :param omega_n: natural frequency (rad/s).
    :param zeta: damping ratio.
    :param period_s: sample period (s).
    :returns: numpy array of taps (length n + 1).
    """
    p = sampled_pole(omega_n, zeta, period_s)
    for n in range(2, max_len):
        idx = (0, n - 1, n)
        zs = [p ** (-i) for i in idx]
        a = np.array([[1.0, 1.0, 1.0], [z.real for z in zs], [z.imag for z in zs]])
        try:
            h = np.linalg.solve(a, np.array([1.0, 0.0, 0.0]))
        except np.linalg.LinAlgError:
            continue
        if np.all(h >= -1e-12):
            taps = np.zeros(n + 1)
            taps[list(idx)] = np.maximum(h, 0.0)
            return taps / taps.sum()
    raise ValueError('no non-negative zero-vibration shaper within %d samples' % max_len)


def design(kind, omega_n, zeta, period_s):
    """Return the taps of a ``none``, ``zv`` or ``zvd`` shaper (see the module docstring)."""
    if kind not in KINDS:
        raise ValueError('unknown shaping %r (allowed: %s)' % (kind, ', '.join(KINDS)))
    if kind == 'none':
        return np.array([1.0])
    h = zv_taps(omega_n, zeta, period_s)
    return np.convolve(h, h) if kind == 'zvd' else h


class Shaper:
    """
    FIR reference shaper: ``step(r)`` returns ``sum_i h_i r_{k-i}`` (m in, m out).

    The history starts at ``initial`` (m; the plant rests at 0 m).
    """

    def __init__(self, taps, initial=0.0):
        """Store the taps (non-negative, summing to 1) and fill the history."""
        taps = [float(x) for x in np.asarray(taps, dtype=float).reshape(-1)]
        if not taps or min(taps) < 0 or abs(sum(taps) - 1.0) > 1e-9:
            raise ValueError('shaper taps must be non-negative and sum to 1')
        self.taps = taps
        self.initial = float(initial)
        self.reset()

    @property
    def delay_s_per_period(self):
        """Length of the shaper in periods (the added delay of a step, in samples)."""
        return len(self.taps) - 1

    def reset(self):
        """Refill the history with the initial value."""
        self.hist = [self.initial] * len(self.taps)
        self.i = 0

    def step(self, r):
        """Push ``r`` (m) and return the shaped reference (m)."""
        n = len(self.taps)
        if n == 1:
            return r
        self.i = (self.i + 1) % n
        self.hist[self.i] = r
        s = 0.0
        h = self.hist
        j = self.i
        for t in self.taps:
            s += t * h[j]
            j -= 1
        return s


class ReferenceModel:
    """
    Predicted plant output for the feedback of the composite controller (m in, m out).

    ``step(r_k)`` returns the displacement the plant should show at sample k if the
    feedforward were exact: the shaped reference passed through the exactly discretised
    unit-gain bending mode, delayed one period like the plant. Feeding the fuzzy PID with
    this instead of the raw reference leaves it only the model error to correct, so it
    does not fight the feedforward during a fast transient.

    :param shaper: the same :class:`Shaper` design the compensator uses (or None).
    :param omega_n: natural frequency (rad/s).
    :param zeta: damping ratio.
    :param period_s: control period (s).
    """

    def __init__(self, shaper, omega_n, zeta, period_s, lead=None):
        """Discretise the mode and start at rest (``lead``: the compensator's Lead)."""
        self.lead = lead
        from fiber_align.plant.actuator import discretise
        ad, bd = discretise(omega_n, zeta, period_s)
        self._a = [float(x) for x in ad.ravel()]
        self._b = [float(x) for x in bd]
        self.shaper = shaper
        self.reset()

    def reset(self):
        """Return to rest at 0 m."""
        if self.shaper is not None:
            self.shaper.reset()
        if self.lead is not None:
            self.lead.reset()
        self.x = 0.0
        self.xd = 0.0

    def step(self, r):
        """Return the predicted displacement (m) now, then advance with reference ``r`` (m)."""
        y = self.x
        if r != r:
            return y
        if r < 0.0:
            r = 0.0
        rs = self.shaper.step(r) if self.shaper is not None else r
        if self.lead is not None:
            rs = self.lead.step(rs)
        a, b = self._a, self._b
        x, xd = self.x, self.xd
        self.x = a[0] * x + a[1] * xd + b[0] * rs
        self.xd = a[2] * x + a[3] * xd + b[1] * rs
        return y


class Lead:
    """
    First-order prediction that cancels the delay of the shaper and of the ZOH (m -> m).

    ``step(r)`` returns ``r + lead_s * dr/dt`` with ``dr/dt`` the backward difference over
    one period, taken as 0 when it exceeds ``max_rate_m_per_s`` (a jump, e.g. a step,
    is not extrapolated). For a ramp this removes a lag of ``lead_s`` exactly; for a
    step it does nothing.

    :param period_s: control period (s).
    :param lead_s: prediction horizon (s).
    :param max_rate_m_per_s: largest reference rate that is extrapolated (m/s).
    """

    def __init__(self, period_s, lead_s, max_rate_m_per_s):
        """Store the horizon and the rate limit."""
        self.period_s = float(period_s)
        self.lead_s = float(lead_s)
        self.max_rate = float(max_rate_m_per_s)
        self.reset()

    def reset(self):
        """Forget the previous sample (the reference starts at rest, 0 m)."""
        self.prev = 0.0

    def step(self, r):
        """Return the predicted reference (m) for ``r`` (m)."""
        d = (r - self.prev) / self.period_s
        self.prev = r
        if d > self.max_rate or d < -self.max_rate:
            return r
        return r + self.lead_s * d


def shaper_delay_s(shaper, period_s):
    """Return the mean delay (s) of a shaper (sum of i h_i times the period)."""
    if shaper is None:
        return 0.0
    return period_s * sum(i * h for i, h in enumerate(shaper.taps))
