# SPDX-License-Identifier: Apache-2.0
"""
Discrete PID with filtered derivative, output clamp and anti-windup.

Per control period ``T`` (s), with error ``e_k`` (m)::

    d_k = a d_{k-1} + (1 - a) (e_k - e_{k-1}) / T      a = exp(-2 pi f_d T)
    I_k = I_{k-1} + ki T e_k
    u_k = clamp(kp e_k + I_k + kd d_k, u_min, u_max)

Gains: ``kp`` in V/m, ``ki`` in V/(m s), ``kd`` in V s/m; output in V. The derivative
acts on the error low-passed at ``derivative_filter_hz`` (first sample: derivative 0).
Anti-windup: ``back-calculation`` adds ``(u_sat - u) T / tracking_time_s`` to the
integral; ``conditional`` freezes the integral while the output is saturated and the
error drives it further into the limit. A NaN error holds the previous output and
counts the event in :attr:`Pid.nan_count`.
"""

import math

from fiber_align.config import ConfigError

ANTI_WINDUP = ('back-calculation', 'conditional', 'none')


class Pid:
    """
    Discrete PID controller; see the module docstring for the law and units.

    :param kp: proportional gain (V/m).
    :param ki: integral gain (V/(m s)).
    :param kd: derivative gain (V s/m).
    :param period_s: control period (s).
    :param derivative_filter_hz: cut-off of the derivative's low-pass (Hz); <= 0 for none.
    :param u_min: lower output limit (V).
    :param u_max: upper output limit (V).
    :param anti_windup: ``back-calculation``, ``conditional`` or ``none``.
    :param tracking_time_s: back-calculation time constant (s); <= 0 means one period.
    """

    def __init__(self, kp, ki, kd, period_s, derivative_filter_hz=0.0, u_min=-math.inf,
                 u_max=math.inf, anti_windup='back-calculation', tracking_time_s=0.0):
        """Store the gains and limits and start at rest."""
        if not period_s > 0:
            raise ValueError('period_s must be > 0, got %r' % period_s)
        if anti_windup not in ANTI_WINDUP:
            raise ConfigError('anti_windup must be one of %s, got %r'
                              % (', '.join(ANTI_WINDUP), anti_windup))
        if not u_max > u_min:
            raise ConfigError('u_max (%g V) must exceed u_min (%g V)' % (u_max, u_min))
        self.period_s = float(period_s)
        self._inv_t = 1.0 / self.period_s
        self.set_gains(kp, ki, kd)
        fd = float(derivative_filter_hz)
        self.deriv_pole = math.exp(-2.0 * math.pi * fd * self.period_s) if fd > 0 else 0.0
        self._deriv_gain = 1.0 - self.deriv_pole
        self.u_min = float(u_min)
        self.u_max = float(u_max)
        self.anti_windup = anti_windup
        tt = float(tracking_time_s)
        self.tracking_gain = self.period_s / tt if tt > 0 else 1.0
        self.reset()

    @classmethod
    def from_params(cls, p, period_s, u_min=None, u_max=None):
        """
        Build from a mapping with every key of the constructor (SI units).

        ``kp``, ``ki``, ``kd``, ``derivative_filter_hz``, ``u_min``, ``u_max`` (unless
        given here), ``anti_windup``, ``tracking_time_s``; a missing one is a ConfigError.
        """
        try:
            return cls(float(p['kp']), float(p['ki']), float(p['kd']), period_s,
                       derivative_filter_hz=float(p['derivative_filter_hz']),
                       u_min=float(p['u_min'] if u_min is None else u_min),
                       u_max=float(p['u_max'] if u_max is None else u_max),
                       anti_windup=str(p['anti_windup']),
                       tracking_time_s=float(p['tracking_time_s']))
        except KeyError as exc:
            raise ConfigError('PID parameters lack %s' % exc) from None

    def set_gains(self, kp, ki, kd):
        """Set the gains (V/m, V/(m s), V s/m) used from the next step on."""
        self.kp = float(kp)
        self.ki = float(ki)
        self.kd = float(kd)

    def reset(self):
        """Clear the integral, the derivative filter and the counters."""
        self.integral = 0.0
        self.deriv = 0.0
        self.e_prev = None
        self.u = 0.0
        self.saturated = False
        self.saturation_count = 0
        self.nan_count = 0
        self.held = False
        #: True: the integral stays as it is (the caller's reference is in a transient
        #: the integral must not learn, e.g. the realtime path's own ramp)
        self.hold_integral = False

    def step(self, e):
        """Advance one period with error ``e`` (m); return the output (V)."""
        if e - e != 0.0:            # NaN or infinite
            self.nan_count += 1
            self.held = True
            return self.u
        self.held = False
        ep = self.e_prev
        de = 0.0 if ep is None else (e - ep) * self._inv_t
        self.e_prev = e
        d = self.deriv_pole * self.deriv + self._deriv_gain * de
        self.deriv = d
        i_new = self.integral if self.hold_integral else \
            self.integral + self.ki * self.period_s * e
        u = self.kp * e + i_new + self.kd * d
        if u > self.u_max:
            u_sat = self.u_max
        elif u < self.u_min:
            u_sat = self.u_min
        else:
            self.saturated = False
            self.integral = i_new
            self.u = u
            return u
        self.saturated = True
        self.saturation_count += 1
        if self.anti_windup == 'back-calculation':
            i_new += (u_sat - u) * self.tracking_gain
        elif self.anti_windup == 'conditional' and (u - u_sat) * e > 0:
            i_new = self.integral
        self.integral = i_new
        self.u = u_sat
        return u_sat
