# SPDX-License-Identifier: Apache-2.0
"""
The first bending mode as a sampled system: what the plant and the controllers share.

The simulated plant advances the mode ``x'' + 2 zeta wn x' + wn^2 x = wn^2 h`` exactly over
each control period; the input shaper, the reference model and the gain search use the
same discretisation, from the design model's resonance (never from the simulated plant).
"""

import functools
import math

import numpy as np

from fiber_align.design.analysis import dynamics


def design_dynamics(actuator):
    """
    Return ``(omega_n_rad_s, alpha_m_per_v)`` of ``actuator`` (beam FE model).

    :param actuator: a :class:`fiber_align.design.Actuator` (already loaded by the caller).
    :returns: natural frequency of the first bending mode (rad/s) and the free tip
        displacement per volt (m/V).
    """
    d = dynamics(actuator)
    return float(d['omega_n_rad_s']), float(d['alpha_m_per_v'])


def discretise(omega_n, zeta, period_s):
    """
    Return ``(Ad, Bd)`` of the exact ZOH discretisation of the 2nd-order mode.

    State ``[x (m), x' (m/s)]``, input the quasi-static displacement ``h`` (m). The
    matrix exponential is taken in closed form for ``zeta < 1`` (with
    ``s = zeta wn``, ``wd = wn sqrt(1 - zeta^2)``, ``E = exp(-s T)``:
    ``Ad = E [[c + s/wd sn, sn/wd], [-wn^2 sn/wd, c - s/wd sn]]``, ``c = cos(wd T)``,
    ``sn = sin(wd T)``, and ``Bd = [1 - Ad_11, -Ad_21]``), otherwise numerically.

    :param omega_n: natural frequency (rad/s).
    :param zeta: damping ratio (dimensionless).
    :param period_s: sample period (s).
    """
    ad, bd = _discretise(float(omega_n), float(zeta), float(period_s))
    return np.array(ad).reshape(2, 2), np.array(bd)


# A memo of a pure function of its three numbers (no configuration in it): the plant, the
# shaper and the gain search ask for the same few periods many times.
@functools.lru_cache(maxsize=64)
def _discretise(omega_n, zeta, period_s):
    """Return ``(Ad as 4 floats row-major, Bd as 2 floats)`` (see :func:`discretise`)."""
    if 0.0 <= zeta < 1.0:
        s = zeta * omega_n
        wd = omega_n * math.sqrt(1.0 - zeta * zeta)
        e = math.exp(-s * period_s)
        c = math.cos(wd * period_s)
        sn = math.sin(wd * period_s) / wd
        a11 = e * (c + s * sn)
        a12 = e * sn
        a21 = -omega_n * omega_n * e * sn
        a22 = e * (c - s * sn)
        return (a11, a12, a21, a22), (1.0 - a11, -a21)
    from scipy.linalg import expm   # heavy, and only for an overdamped mode
    a = np.array([[0.0, 1.0, 0.0],
                  [-omega_n ** 2, -2.0 * zeta * omega_n, omega_n ** 2],
                  [0.0, 0.0, 0.0]])
    m = expm(a * period_s)
    return tuple(float(x) for x in m[:2, :2].ravel()), tuple(float(x) for x in m[:2, 2])
