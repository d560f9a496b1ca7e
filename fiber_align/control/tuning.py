# SPDX-License-Identifier: Apache-2.0
"""
Re-runnable gain search and the linearised stability check of the feedback loop.

``python -m fiber_align.control.tuning [--rate HZ]`` grid-searches the plain PID on the
plant without hysteresis (the paper's Figure 20 case, noise off): it keeps the gain sets
whose linearised closed loop is stable for a plant slope from 0.5 to 1.5 times the
design's alpha (the hysteresis changes the local slope) and whose 82 um step overshoots
by at most 2 %, and prints the one with the shortest 2 % settling time. Gains are
searched as loop gains (gain times alpha: 1/s for ki, s for kd) and printed in SI.
"""

import argparse
import itertools

import numpy as np

from fiber_align.control.pid import Pid
from fiber_align.plant.actuator import design_dynamics, discretise


def closed_loop_matrix(kp, ki, kd, derivative_filter_hz, period_s, omega_n, zeta, alpha):
    """
    Return the state matrix of the linearised loop (plant mode + PID), reference 0.

    State ``[x, x', I, d, e_prev]``; the plant is ``alpha`` (m/V) times the exactly
    discretised mode, the PID is :class:`fiber_align.control.pid.Pid` without limits.
    """
    ad, bd = discretise(omega_n, zeta, period_s)
    a = np.exp(-2 * np.pi * derivative_filter_hz * period_s) if derivative_filter_hz > 0 \
        else 0.0

    def f(z):
        x, xd, integ, d, ep = z
        e = -x
        d2 = a * d + (1 - a) * (e - ep) / period_s
        i2 = integ + ki * period_s * e
        u = kp * e + i2 + kd * d2
        xn = ad @ np.array([x, xd]) + bd * alpha * u
        return np.array([xn[0], xn[1], i2, d2, e])
    return np.column_stack([f(col) for col in np.eye(5)])


def spectral_radius(*args):
    """Return the largest pole magnitude of :func:`closed_loop_matrix` (< 1: stable)."""
    return float(np.max(np.abs(np.linalg.eigvals(closed_loop_matrix(*args)))))


def step_settling(kp, ki, kd, fd, rate_hz, omega_n, alpha, zeta=0.03, duration_s=0.04):
    """Return ``(settling_s, overshoot_pct)`` of an 82 um step on the linear plant."""
    from fiber_align.analysis.metrics import step_metrics
    from fiber_align.hysteresis.truth import Linear
    from fiber_align.plant.actuator import SimulatedActuator
    period = 1.0 / rate_hz
    p = SimulatedActuator(period, Linear(alpha), omega_n, zeta, v_min=-20, v_max=100)
    c = Pid(kp, ki, kd, period, fd, -100, 100)
    y = p.reset()
    ys = []
    for _ in range(int(duration_s * rate_hz)):
        ys.append(p.x)
        y = p.step(c.step(82e-6 - y))
    m = step_metrics(np.arange(len(ys)) * period, np.array(ys), 82e-6)
    return m['settling_time_s'], m['overshoot_pct']


def search(rate_hz, zeta=0.03):
    """Grid-search the PID at ``rate_hz``; return a list of (settling, overshoot, gains)."""
    wn, alpha = design_dynamics()
    period = 1.0 / rate_hz
    kia = [50, 100, 150, 200, 300, 400, 600, 800, 1000, 1400, 2000]
    kpa = [-0.1, 0.0, 0.1, 0.2]
    kda = [0.0, 5e-5, 1e-4, 1.5e-4] if rate_hz > 2000 else [0.0]
    fds = [3000.0] if rate_hz > 2000 else [0.0]
    out = []
    for ki, kp, kd, fd in itertools.product(kia, kpa, kda, fds):
        g = (kp / alpha, ki / alpha, kd / alpha)
        if any(spectral_radius(*g, fd, period, wn, zeta, alpha * s) >= 0.999
               for s in (0.5, 1.0, 1.5)):
            continue
        st, ov = step_settling(*g, fd, rate_hz, wn, alpha, zeta)
        if ov <= 2.0:
            out.append((st, ov, g + (fd,)))
    out.sort(key=lambda x: x[0])
    return out


def main(argv=None):
    """Print the best gains for each rate."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--rate', type=float, action='append')
    args = ap.parse_args(argv)
    for rate in args.rate or [1000.0, 10000.0]:
        res = search(rate)
        print('rate %g Hz: %d stable candidates' % (rate, len(res)))
        for st, ov, g in res[:5]:
            print('  settling %.2f ms overshoot %.2f %%  kp %.6g ki %.6g kd %.6g fd %g'
                  % ((st * 1e3, ov) + g))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
