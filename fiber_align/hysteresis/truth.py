# SPDX-License-Identifier: Apache-2.0
"""
Reference ("true") hysteresis laws for the simulated plant and for identification tests.

``make_hysteresis(kind)`` returns an object with ``.step(u_v) -> m``, ``.reset()`` and
``.simulate(u_array) -> m_array`` (input voltage in V, output displacement in m):

``dense-pi``
    A dense Prandtl-Ishlinskii model (default 50 operators on 0-100 V) whose weights
    fall off smoothly (exponentially) with the threshold, all positive, so the model is
    monotone for any drive up to and beyond 100 V. Scaled so the 0-72 V loading curve
    peaks at ``peak_m`` (70 um); the 0.1 Hz 0-72 V loop is about 13 % of the span wide.
``bouc-wen``
    The rate-independent Bouc-Wen law (n = 1) ``y = d u - h``,
    ``dh = a d du - b |du| h - g du |h|``. Between samples ``u`` is taken as linear, so
    ``h`` follows a piecewise exponential in ``u`` that is integrated exactly: the law
    is well-behaved at any sampling rate (1 Hz to 10 kHz give the same loop).
    ``d`` is scaled so the 0-72 V loading curve peaks at ``peak_m``.
``paper``
    The paper's Table 3 PI model, loaded from ``config/hysteresis_paper.yaml``.
``linear``
    ``alpha u`` with ``alpha`` (m/V) given by the caller (the plant passes the design
    model's, :func:`fiber_align.design.mode.design_dynamics`).

The laws' parameters live in ``config/plant_hysteresis.yaml`` (node ``hysteresis_truth``).
"""

import math

import numpy as np

from fiber_align.config import ConfigError, load_params
from fiber_align.hysteresis.pi import PIModel

KINDS = ('dense-pi', 'bouc-wen', 'paper', 'linear')
CONFIG_FILE = 'plant_hysteresis.yaml'
CONFIG_NODE = 'hysteresis_truth'
# The keys of each section of config/plant_hysteresis.yaml (the only place with values).
SECTION_KEYS = {
    'dense_pi': ('n_operators', 'max_threshold_v', 'linear_fraction', 'decay_v', 'peak_m',
                 'peak_v'),
    'bouc_wen': ('a', 'b_per_v', 'g_per_v', 'peak_m', 'peak_v'),
}


def _section(params, name):
    """Return the nested mapping ``params[name]`` (ROS dotted or nested form)."""
    if isinstance(params.get(name), dict):
        return dict(params[name])
    prefix = name + '.'
    return {k[len(prefix):]: v for k, v in params.items() if k.startswith(prefix)}


def dense_pi(n_operators, max_threshold_v, linear_fraction, decay_v, peak_m, peak_v):
    """
    Build the dense PI "truth" model.

    :param n_operators: number of play operators.
    :param max_threshold_v: largest threshold (V); thresholds are evenly spaced from 0.
    :param linear_fraction: share of the total weight on the zero-threshold operator.
    :param decay_v: e-folding threshold (V) of the weights of the other operators.
    :param peak_m: loading-curve output (m) at ``peak_v`` (V).
    :returns: a :class:`PIModel` with all weights positive (m/V).
    """
    n = int(n_operators)
    if n < 2:
        raise ValueError('dense-pi needs at least 2 operators, got %d' % n)
    if not 0.0 < linear_fraction <= 1.0:
        raise ValueError('linear_fraction must be in (0, 1], got %g' % linear_fraction)
    r = np.linspace(0.0, float(max_threshold_v), n)
    w = np.exp(-r / float(decay_v))
    w[0] = 0.0
    w *= (1.0 - linear_fraction) / w.sum()
    w[0] = linear_fraction
    model = PIModel(r, w)
    w = w * (float(peak_m) / float(model.loading_curve(float(peak_v))))
    return PIModel(r, w)


class BoucWen:
    """
    Rate-independent Bouc-Wen hysteresis ``u (V) -> y (m)``, exactly integrated.

    ``y = d u - h`` with ``dh/du = a d - (b sgn(du) + g sgn(h)) h`` (n = 1), ``u``
    linear between samples. Units: ``d`` in m/V, ``h`` in m, ``a`` dimensionless,
    ``b`` and ``g`` in 1/V.

    :param d_m_per_v: piezo coefficient (m/V).
    :param a: ``alpha`` (dimensionless, 0 < a < 1 keeps the law monotone).
    :param b_per_v: ``beta`` (1/V).
    :param g_per_v: ``gamma`` (1/V), ``|g| <= b``.
    """

    def __init__(self, d_m_per_v, a, b_per_v, g_per_v):
        """Store the parameters and start at rest (u = 0, h = 0)."""
        if not 0.0 < a < 1.0:
            raise ValueError('Bouc-Wen a must be in (0, 1), got %g' % a)
        if b_per_v <= 0.0 or abs(g_per_v) > b_per_v:
            raise ValueError('Bouc-Wen needs b > 0 and |g| <= b (got b=%g, g=%g)'
                             % (b_per_v, g_per_v))
        self.d = float(d_m_per_v)
        self.a = float(a)
        self.b = float(b_per_v)
        self.g = float(g_per_v)
        self.reset()

    def reset(self):
        """Return to rest: u = 0 V, h = 0 m."""
        self._u = 0.0
        self._h = 0.0

    @property
    def state(self):
        """Return ``(u_v, h_m)``, the last input (V) and the hysteretic term (m)."""
        return self._u, self._h

    def _advance(self, h, du):
        """Integrate ``h`` exactly over an input increment ``du`` (V); return h (m)."""
        if du == 0.0:
            return h
        sgn = 1.0 if du > 0.0 else -1.0
        x = abs(du)        # distance left to travel, V
        ad = self.a * self.d * sgn   # dh/dx source term along the travel direction
        for _ in range(3):  # at most one sign change of h per monotone segment
            hs = 1.0 if h > 0.0 else (-1.0 if h < 0.0 else (1.0 if ad > 0 else -1.0))
            # dh/dx = ad - c h, with c = b + g sgn(du) sgn(h)   (x = |u - u0|)
            c = self.b + self.g * sgn * hs
            if c <= 0.0:
                return h + ad * x  # degenerate (|g| = b): linear growth
            hinf = ad / c
            # Does h reach 0 (sign change) before x runs out?
            if h != 0.0 and (hinf * h) < 0.0:
                x0 = math.log((h - hinf) / (0.0 - hinf)) / c
                if x0 < x:
                    x -= x0
                    h = 0.0
                    continue
            return hinf + (h - hinf) * math.exp(-c * x)
        return h

    def step(self, u):
        """Advance to input ``u`` (V); return the displacement (m)."""
        u = float(u)
        self._h = self._advance(self._h, u - self._u)
        self._u = u
        return self.d * u - self._h

    def simulate(self, u, reset=True):
        """Run an input sequence (V) from rest (default); return displacements (m)."""
        if reset:
            self.reset()
        u = np.asarray(u, dtype=float).reshape(-1)
        return np.array([self.step(x) for x in u.tolist()])


def bouc_wen(a, b_per_v, g_per_v, peak_m, peak_v):
    """Build the Bouc-Wen "truth" with ``d`` scaled to ``peak_m`` at ``peak_v`` (m, V)."""
    bw = BoucWen(1.0, a, b_per_v, g_per_v)
    y1 = bw.step(float(peak_v))
    if not y1 > 0.0:
        raise ValueError('Bouc-Wen parameters give no positive displacement at %g V' % peak_v)
    bw.d = float(peak_m) / y1
    bw.reset()
    return bw


class Linear:
    """A hysteresis-free actuator ``y = alpha u`` (alpha in m/V)."""

    def __init__(self, alpha_m_per_v):
        """Store ``alpha`` (m/V)."""
        self.alpha = float(alpha_m_per_v)

    def reset(self):
        """Do nothing: the law has no state."""

    def step(self, u):
        """Return ``alpha u`` (m) for input ``u`` (V)."""
        return self.alpha * float(u)

    def simulate(self, u, reset=True):
        """Return ``alpha u`` (m) for an input sequence (V)."""
        return self.alpha * np.asarray(u, dtype=float).reshape(-1)


def make_hysteresis(kind, params=None, config=CONFIG_FILE, alpha_m_per_v=None):
    """
    Return a hysteresis law ``u (V) -> y (m)`` with ``step``, ``reset``, ``simulate``.

    :param kind: one of ``dense-pi``, ``bouc-wen``, ``paper``, ``linear``.
    :param params: overrides for the kind's section of the config (SI units).
    :param config: params file with the laws' parameters (node ``hysteresis_truth``).
    :param alpha_m_per_v: slope of the ``linear`` law (m/V), the design model's
        (:func:`fiber_align.design.mode.design_dynamics`); needed for ``linear`` only.
    :raises ConfigError: a section or key missing from ``config``.
    """
    if kind not in KINDS:
        raise ValueError('unknown hysteresis kind %r (allowed: %s)' % (kind, ', '.join(KINDS)))
    if kind == 'paper':
        return PIModel.load('hysteresis_paper.yaml')
    if kind == 'linear':
        if alpha_m_per_v is None:
            raise ValueError('the linear law needs alpha_m_per_v (m/V) of the design model')
        return Linear(alpha_m_per_v)
    name = kind.replace('-', '_')
    sec = _section(load_params(config, CONFIG_NODE), name)
    sec.update(params or {})
    keys = SECTION_KEYS[name]
    missing = [k for k in keys if k not in sec]
    unknown = sorted(set(sec) - set(keys))
    if missing or unknown:
        raise ConfigError('%s: section %s.%s: missing %s, unknown %s (allowed: %s)'
                          % (config, CONFIG_NODE, name, missing or 'none',
                             unknown or 'none', ', '.join(keys)))
    return (dense_pi if kind == 'dense-pi' else bouc_wen)(**sec)
