# SPDX-License-Identifier: Apache-2.0
"""
The simulated actuator (plant): amplifier, hysteresis, resonance and sensor.

One call of :meth:`SimulatedActuator.step` is one control period ``T`` (s):

1. the drive voltage ``v`` (V) is held for the whole period (zero-order hold);
2. the amplifier clamps it to ``[v_min, v_max]`` (V) and limits its change per period to
   ``slew_rate_v_per_s * T`` (V) (the ramp inside a period is not modelled);
3. the hysteresis law maps the applied voltage to a quasi-static displacement ``h`` (m);
4. the bending mode ``x'' + 2 zeta wn x' + wn^2 x = wn^2 h`` is advanced exactly over
   the period (matrix exponential of the continuous model, not Euler: the resonance near
   1.4 kHz is close to the control rate);
5. the sensor adds seeded Gaussian noise (m RMS) and rounds to its resolution (m).

A Prandtl-Ishlinskii law (``dense-pi``, ``paper``) is stepped by a
:class:`fiber_align.hysteresis.playbank.PlayBank` built from it (same output in amortised
O(1) instead of O(n) per period); other laws by their own ``step``.

The displacement per volt ``alpha`` is the slope of the hysteresis law (``linear`` law:
``alpha`` of the design model), the natural frequency ``wn`` comes from the design model
(:func:`fiber_align.design.dynamics`) unless set. The noise comes from
``numpy.random.default_rng(seed)``, one standard-normal draw per measurement, so a run is
deterministic for a seed and the ROS plant node reproduces it sample for sample.
"""

import copy
import math

import numpy as np

from fiber_align.config import ConfigError, load_params
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics, discretise
from fiber_align.hysteresis.pi import PIModel
from fiber_align.hysteresis.playbank import PlayBank
from fiber_align.hysteresis.truth import make_hysteresis

CONFIG_FILE = 'plant.yaml'
CONFIG_NODE = 'simulated_actuator'
DESIGN_FILE = 'actuator.yaml'
# The plant's hysteresis laws: ``default`` is the dense-PI truth.
KINDS = ('default', 'paper', 'linear', 'dense-pi', 'bouc-wen')
PARAM_KEYS = ('rate_hz', 'hysteresis', 'omega_n_rad_s', 'damping_ratio', 'v_min', 'v_max',
              'slew_rate_v_per_s', 'noise_rms_m', 'resolution_m', 'seed')
_NOISE_BLOCK = 4096


def make_law(kind, alpha_m_per_v):
    """
    Return a new plant hysteresis law for ``kind`` (``default`` = ``dense-pi``), at rest.

    :param kind: a name in :data:`KINDS`.
    :param alpha_m_per_v: slope of the ``linear`` law (m/V), the design model's.
    """
    if kind not in KINDS:
        raise ConfigError('unknown hysteresis %r (allowed: %s)' % (kind, ', '.join(KINDS)))
    kind = 'dense-pi' if kind == 'default' else kind
    return make_hysteresis(kind, alpha_m_per_v=alpha_m_per_v)


class SimulatedActuator:
    """
    The plant: ``step(v)`` applies ``v`` (V) for one period and returns the measurement (m).

    :param period_s: control period ``T`` (s).
    :param hysteresis: law with ``step(u_v) -> m`` and ``reset()``; a
        :class:`~fiber_align.hysteresis.pi.PIModel` is stepped through a
        :class:`~fiber_align.hysteresis.playbank.PlayBank` copy (the law object itself is
        then only reset, not advanced; :attr:`h` is its output).
    :param omega_n_rad_s: natural frequency of the bending mode (rad/s).
    :param damping_ratio: modal damping ratio (dimensionless).
    :param v_min: amplifier lower limit (V).
    :param v_max: amplifier upper limit (V).
    :param slew_rate_v_per_s: amplifier slew limit (V/s); ``inf`` or <= 0 for none.
    :param noise_rms_m: sensor noise (m RMS); 0 for none.
    :param resolution_m: sensor resolution (m); 0 for none.
    :param seed: seed of the noise generator.
    :param nan_samples: measurement indices (0 = before the first step) that read NaN,
        to exercise fault handling.
    """

    def __init__(self, period_s, hysteresis, omega_n_rad_s, damping_ratio,
                 v_min=0.0, v_max=100.0, slew_rate_v_per_s=math.inf, noise_rms_m=0.0,
                 resolution_m=0.0, seed=0, nan_samples=()):
        """Build the plant at rest (see the class docstring for the units)."""
        if not period_s > 0:
            raise ValueError('period_s must be > 0, got %r' % period_s)
        if not omega_n_rad_s > 0:
            raise ValueError('omega_n_rad_s must be > 0, got %r' % omega_n_rad_s)
        if not 0 <= damping_ratio < 1:
            raise ValueError('damping_ratio must be in [0, 1), got %r' % damping_ratio)
        if not v_max > v_min:
            raise ValueError('v_max (%g V) must exceed v_min (%g V)' % (v_max, v_min))
        if noise_rms_m < 0 or resolution_m < 0:
            raise ValueError('noise_rms_m and resolution_m must be >= 0')
        self.period_s = float(period_s)
        self.hysteresis = hysteresis
        self.omega_n_rad_s = float(omega_n_rad_s)
        self.damping_ratio = float(damping_ratio)
        self.v_min = float(v_min)
        self.v_max = float(v_max)
        slew = float(slew_rate_v_per_s)
        self.max_dv = slew * self.period_s if slew > 0 and math.isfinite(slew) else math.inf
        self.noise_rms_m = float(noise_rms_m)
        self.resolution_m = float(resolution_m)
        self.seed = int(seed)
        self.nan_samples = frozenset(int(i) for i in nan_samples)
        ad, bd = discretise(self.omega_n_rad_s, self.damping_ratio, self.period_s)
        self._a = [float(x) for x in ad.ravel()]
        self._b = [float(x) for x in bd]
        self._c = tuple(self._a + self._b)
        # A PI law is stepped by a bank of its own, so the law object is only reset.
        self._bank = PlayBank.from_model(hysteresis) if isinstance(hysteresis, PIModel) \
            else None
        self.reset()

    @classmethod
    def from_params(cls, params, period_s=None, dynamics=None, **overrides):
        """
        Build from a ``simulated_actuator`` parameter mapping (see ``config/plant.yaml``).

        :param params: the mapping (every key of ``config/plant.yaml``; ``nan_samples``,
            a fault-injection list of tests, is optional); ``hysteresis`` names the
            law, ``omega_n_rad_s`` <= 0 takes the design model's value, ``rate_hz`` sets
            the period unless ``period_s`` (s) is given.
        :param dynamics: ``(omega_n_rad_s, alpha_m_per_v)`` of the design model
            (:func:`fiber_align.design.mode.design_dynamics`), loaded by the caller; None
            loads ``config/actuator.yaml`` here.
        :param overrides: keyword arguments of the constructor that win over ``params``
            (``hysteresis`` may be a kind name or a law object).
        :raises ConfigError: a missing or unknown key.
        """
        p = dict(params)
        p.update({k: v for k, v in overrides.items() if v is not None})
        unknown = sorted(set(p) - set(PARAM_KEYS) - {'nan_samples'})
        if unknown:
            raise ConfigError('unknown simulated_actuator parameter(s): %s (allowed: %s)'
                              % (', '.join(unknown), ', '.join(PARAM_KEYS)))
        needed = [k for k in PARAM_KEYS if k not in p
                  and not (k == 'rate_hz' and period_s is not None)]
        if needed:
            raise ConfigError('%s: missing simulated_actuator parameter(s): %s'
                              % (CONFIG_FILE, ', '.join(needed)))
        if period_s is None:
            period_s = 1.0 / float(p['rate_hz'])
        law = p['hysteresis']
        wn = float(p['omega_n_rad_s'])
        if dynamics is None and (wn <= 0 or law == 'linear'):
            dynamics = design_dynamics(load_actuator(DESIGN_FILE))
        if isinstance(law, str):
            law = make_law(law, None if dynamics is None else dynamics[1])
        if wn <= 0:
            wn = dynamics[0]
        return cls(period_s, law, wn, float(p['damping_ratio']),
                   v_min=float(p['v_min']), v_max=float(p['v_max']),
                   slew_rate_v_per_s=float(p['slew_rate_v_per_s']),
                   noise_rms_m=float(p['noise_rms_m']),
                   resolution_m=float(p['resolution_m']),
                   seed=int(p['seed']), nan_samples=p.get('nan_samples', ()))

    @classmethod
    def from_config(cls, path=CONFIG_FILE, period_s=None, dynamics=None, **overrides):
        """Build from a params file (default ``config/plant.yaml``, node simulated_actuator)."""
        return cls.from_params(load_params(path, CONFIG_NODE), period_s, dynamics,
                               **overrides)

    # -- state ------------------------------------------------------------------------
    def reset(self, seed=None):
        """Return to rest at 0 V, restart the noise generator; return the first measurement (m)."""
        if seed is not None:
            self.seed = int(seed)
        self.hysteresis.reset()
        if self._bank is not None:
            self._bank.reset(self.hysteresis.state)
            self._law_step = self._bank.step
        else:
            self._law_step = self.hysteresis.step
        self._rng = np.random.default_rng(self.seed)
        self._noise = []
        self._noise_i = 0
        self.x = 0.0
        self.xd = 0.0
        self.h = 0.0
        self.v_applied = 0.0
        self.k = 0
        self.y_meas = self._measure()
        return self.y_meas

    def _measure(self):
        """Draw the sensor reading (m) of the present position."""
        y = self.x
        if self.noise_rms_m > 0:
            if self._noise_i >= len(self._noise):
                self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
                self._noise_i = 0
            y += self.noise_rms_m * self._noise[self._noise_i]
            self._noise_i += 1
        if self.resolution_m > 0:
            y = round(y / self.resolution_m) * self.resolution_m
        if self.k in self.nan_samples:
            y = math.nan
        return y

    @property
    def position_m(self):
        """Give the true displacement (m) now."""
        return self.x

    @property
    def velocity_m_per_s(self):
        """Give the true velocity (m/s) now."""
        return self.xd

    def reachable_m(self):
        """Return the largest quasi-static displacement (m): the loading curve at ``v_max``."""
        law = self.hysteresis
        if hasattr(law, 'loading_curve'):
            return float(law.loading_curve(self.v_max))
        probe = copy.deepcopy(law)
        probe.reset()
        y = 0.0
        for u in np.linspace(0.0, self.v_max, 201):
            y = probe.step(float(u))
        return float(y)

    def step(self, v):
        """
        Apply the drive ``v`` (V) for one period; return the new measurement (m).

        A non-finite drive is treated as a fault of the driver: the amplifier holds its
        previous output.
        """
        v = float(v)
        va = self.v_applied
        if v - v != 0.0:            # NaN or infinite
            v = va
        if v > self.v_max:
            v = self.v_max
        elif v < self.v_min:
            v = self.v_min
        dv = v - va
        mdv = self.max_dv
        if dv > mdv:
            v = va + mdv
        elif dv < -mdv:
            v = va - mdv
        self.v_applied = v
        h = self.h = self._law_step(v)
        a0, a1, a2, a3, b0, b1 = self._c
        x = self.x
        xd = self.xd
        y = self.x = a0 * x + a1 * xd + b0 * h
        self.xd = a2 * x + a3 * xd + b1 * h
        k = self.k = self.k + 1
        # the sensor, as in _measure
        if self.noise_rms_m > 0:
            i = self._noise_i
            if i >= len(self._noise):
                self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
                i = 0
            y += self.noise_rms_m * self._noise[i]
            self._noise_i = i + 1
        res = self.resolution_m
        if res > 0:
            y = round(y / res) * res
        if self.nan_samples and k in self.nan_samples:
            y = math.nan
        self.y_meas = y
        return y
