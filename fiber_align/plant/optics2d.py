# SPDX-License-Identifier: Apache-2.0
"""
Optical coupling in two axes: the input core at ``(x, y)``, the output core at a target.

The rig's link in :mod:`fiber_align.plant.link` terms: one facet of two axes (x, y; m), two
equal Gaussian modes of radius ``w`` (m) across an end-face gap ``z`` (m), no chip::

    eta = exp(-(dx^2 + dy^2) / (w^2 q)) / q,   q = 1 + Z^2,   Z = lambda z / (2 pi n w^2)

the 1-D model of :mod:`fiber_align.plant.optics` with ``d^2 = dx^2 + dy^2``: the overlap
integral of two circular Gaussians separates into the product of an x and a y factor, so
``eta(dx, dy) q = (eta(dx) q) (eta(dy) q)``. The 1-D model has no tilt term, so neither has
this one. ``ln P`` is a paraboloid in ``(x, y)``, which the 2-D peak fit exploits.

The target moves: ``s(t) = s0 + v t + a u sin(2 pi f t)`` with ``v`` the drift velocity
(m/s, any direction), ``a`` the vibration amplitude (m), ``f`` its frequency (Hz) and ``u``
the unit vector at ``vibration_angle_rad`` from the x axis.

The link constants (source, wavelength, mode radius, gap, detector) are the ones of
``config/optics.yaml`` (one source for both models); the target is in
``config/optics2d.yaml`` (node ``simulated_optics_2d``, nested under ``target``).
"""

import math

import numpy as np

from fiber_align.plant import link as ln

CONFIG_FILE = 'optics2d.yaml'
CONFIG_NODE = 'simulated_optics_2d'
TARGET_KEYS = ('position_x_m', 'position_y_m', 'drift_x_m_per_s', 'drift_y_m_per_s',
               'vibration_amplitude_m', 'vibration_frequency_hz', 'vibration_angle_rad')
LINK_KEYS = ('source_power_w', 'wavelength_m', 'mode_radius_m', 'gap_m', 'index',
             'fiber_broken')
DETECTOR_KEYS = ln.DETECTOR_KEYS


def coupling_efficiency_2d(dx_m, dy_m, gap_m=0.0, mode_radius_m=5.2e-6, wavelength_m=1.55e-6,
                           index=1.0):
    """
    Return the power coupling efficiency (0..1) for a lateral offset ``(dx, dy)`` (m).

    :param dx_m: offset along x (m), scalar or array.
    :param dy_m: offset along y (m), scalar or array (broadcast with ``dx_m``).
    :param gap_m: axial gap (m).
    :param mode_radius_m: mode-field radius ``w`` (m).
    :param wavelength_m: vacuum wavelength (m).
    :param index: refractive index of the gap medium.
    """
    eta0, c = ln.overlap(mode_radius_m, mode_radius_m, gap_m, wavelength_m, index)
    d2 = np.asarray(dx_m, dtype=float) ** 2 + np.asarray(dy_m, dtype=float) ** 2
    out = eta0 * np.exp(-c * d2)
    return float(out) if out.ndim == 0 else out


def offset_loss_db(offset_m, gap_m=0.0, mode_radius_m=5.2e-6, wavelength_m=1.55e-6,
                   index=1.0):
    """Return the loss (dB) of a lateral offset (m) against the aligned coupling."""
    c = ln.overlap(mode_radius_m, mode_radius_m, gap_m, wavelength_m, index)[1]
    return 10.0 / math.log(10.0) * c * offset_m ** 2


class Target(ln.Target):
    """The output core's position (m) over time, from the keys of ``optics2d.yaml``."""

    def __init__(self, position_x_m=30e-6, position_y_m=30e-6, drift_x_m_per_s=0.0,
                 drift_y_m_per_s=0.0, vibration_amplitude_m=0.0, vibration_frequency_hz=0.0,
                 vibration_angle_rad=0.0):
        """Store the start (m), drift (m/s), vibration (m, Hz) and its angle from x (rad)."""
        a = float(vibration_angle_rad)
        super().__init__((position_x_m, position_y_m), (drift_x_m_per_s, drift_y_m_per_s),
                         vibration_amplitude_m, vibration_frequency_hz,
                         (math.cos(a), math.sin(a)))


class FiberCoupling2D(ln.Coupling):
    """Noise-free coupled power (W) as a function of time and the tip position ``(x, y)``."""

    def __init__(self, target, source_power_w=1e-3, wavelength_m=1.55e-6,
                 mode_radius_m=5.2e-6, gap_m=10e-6, index=1.0, fiber_broken=False):
        """Store the link constants (SI: W, m); ``target`` is a :class:`Target`."""
        self.target = target
        self.gap_m = float(gap_m)
        self.mode_radius_m = float(mode_radius_m)
        facet = ln.Facet((0, 1), target, mode_radius_m, mode_radius_m, gap_m, wavelength_m,
                         index)
        super().__init__(source_power_w, (facet,), 1.0, fiber_broken)
        self.curvature_per_m2 = facet.curvature_per_m2

    def power_w(self, t_s, x_m, y_m):
        """Return the true coupled power (W) with the input core at ``(x_m, y_m)`` at ``t_s``."""
        return self.power_at(t_s, (x_m, y_m))

    def loss_db(self, t_s, x_m, y_m):
        """Return the true loss (dB) against the (moving) maximum at ``t_s``."""
        return self.loss_at(t_s, (x_m, y_m))


class OpticalLink2D(ln.Link):
    """Coupling in two axes plus the 1-D model's :class:`~fiber_align.plant.optics.Detector`."""

    @classmethod
    def from_params(cls, optics_params=None, target_params=None, seed=0, **overrides):
        """
        Build a link; ``overrides`` replace keys of either mapping.

        :param optics_params: the ``optics`` mapping of ``config/optics.yaml`` (``None``
            loads it); the 1-D slot keys in it are ignored.
        :param target_params: the ``target`` mapping of ``config/optics2d.yaml`` (``None``
            loads it).
        :param seed: detector noise seed.
        """
        o, tg = ln.sections(optics_params, target_params, CONFIG_FILE, CONFIG_NODE, 'target')
        ln.split_overrides(overrides, ((TARGET_KEYS, tg), (LINK_KEYS + DETECTOR_KEYS, o)),
                           '2-D optics')
        unknown = sorted(set(tg) - set(TARGET_KEYS))
        if unknown:
            raise ValueError('unknown target parameter(s): %s (known: %s)'
                             % (', '.join(unknown), ', '.join(TARGET_KEYS)))
        coupling = FiberCoupling2D(Target(**tg), **{k: o[k] for k in LINK_KEYS if k in o})
        return cls(coupling, ln.detector(o, seed))

    def true_power_w(self, t_s, x_m, y_m):
        """Return the noise-free coupled power (W)."""
        return super().true_power_w(t_s, (x_m, y_m))

    def measure(self, t_s, x_m, y_m, dt_s=None):
        """Return the detector reading (W) with the core at ``(x_m, y_m)`` (m) at ``t_s``."""
        return super().measure(t_s, (x_m, y_m), dt_s)

    def loss_db(self, t_s, x_m, y_m):
        """Return the true loss (dB) against the (moving) maximum."""
        return super().loss_db(t_s, (x_m, y_m))


def load_optics2d(seed=0, **overrides):
    """Return an :class:`OpticalLink2D` from ``optics.yaml`` and ``optics2d.yaml``."""
    return OpticalLink2D.from_params(None, None, seed=seed, **overrides)
