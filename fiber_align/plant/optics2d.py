# SPDX-License-Identifier: Apache-2.0
"""
Optical coupling in two axes: the input core at ``(x, y)``, the output core at a target.

The input fiber rides on two bimorphs (x and y, m); the output core sits at the target
``(s_x(t), s_y(t))`` (m), unknown to the sequencer. Two equal Gaussian modes of radius ``w``
(m) with a lateral offset ``(dx, dy)`` (m) and an end-face gap ``z`` (m) couple::

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

from fiber_align.config import load_params
from fiber_align.plant import optics as op

CONFIG_FILE = 'optics2d.yaml'
CONFIG_NODE = 'simulated_optics_2d'
TARGET_KEYS = ('position_x_m', 'position_y_m', 'drift_x_m_per_s', 'drift_y_m_per_s',
               'vibration_amplitude_m', 'vibration_frequency_hz', 'vibration_angle_rad')
LINK_KEYS = ('source_power_w', 'wavelength_m', 'mode_radius_m', 'gap_m', 'index',
             'fiber_broken')
DETECTOR_KEYS = ('noise_floor_w', 'rin_db', 'averaging_time_s', 'saturation_w',
                 'sample_period_s')


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
    q = op.rayleigh_factor(gap_m, mode_radius_m, wavelength_m, index)
    dx = np.asarray(dx_m, dtype=float)
    dy = np.asarray(dy_m, dtype=float)
    # separable: the x factor times the y factor, the gap term counted once
    out = (np.exp(-(dx / mode_radius_m) ** 2 / q) * np.exp(-(dy / mode_radius_m) ** 2 / q)
           / q)
    return float(out) if out.ndim == 0 else out


def offset_loss_db(offset_m, gap_m=0.0, mode_radius_m=5.2e-6, wavelength_m=1.55e-6,
                   index=1.0):
    """Return the loss (dB) of a lateral offset (m) against the aligned coupling."""
    q = op.rayleigh_factor(gap_m, mode_radius_m, wavelength_m, index)
    return 10.0 / math.log(10.0) * (offset_m / mode_radius_m) ** 2 / q


class Target:
    """
    The output core's position (m) over time: start, drift velocity and vibration.

    :param position_x_m: x at ``t = 0`` (m).
    :param position_y_m: y at ``t = 0`` (m).
    :param drift_x_m_per_s: drift velocity along x (m/s).
    :param drift_y_m_per_s: drift velocity along y (m/s).
    :param vibration_amplitude_m: vibration amplitude (m).
    :param vibration_frequency_hz: vibration frequency (Hz).
    :param vibration_angle_rad: direction of the vibration from the x axis (rad).
    """

    def __init__(self, position_x_m=30e-6, position_y_m=30e-6, drift_x_m_per_s=0.0,
                 drift_y_m_per_s=0.0, vibration_amplitude_m=0.0, vibration_frequency_hz=0.0,
                 vibration_angle_rad=0.0):
        """Store the motion (SI)."""
        self.x0 = float(position_x_m)
        self.y0 = float(position_y_m)
        self.vx = float(drift_x_m_per_s)
        self.vy = float(drift_y_m_per_s)
        self.amp = float(vibration_amplitude_m)
        self.freq = float(vibration_frequency_hz)
        self.angle = float(vibration_angle_rad)

    def position(self, t_s):
        """Return ``(x, y)`` (m) of the output core at ``t_s`` (s); scalars or arrays."""
        t = np.asarray(t_s, dtype=float)
        x = self.x0 + self.vx * t
        y = self.y0 + self.vy * t
        if self.amp:
            v = self.amp * np.sin(2.0 * math.pi * self.freq * t)
            x = x + v * math.cos(self.angle)
            y = y + v * math.sin(self.angle)
        if t.ndim == 0:
            return float(x), float(y)
        return x, y


class FiberCoupling2D:
    """Noise-free coupled power (W) as a function of time and the tip position ``(x, y)``."""

    def __init__(self, target, source_power_w=1e-3, wavelength_m=1.55e-6,
                 mode_radius_m=5.2e-6, gap_m=10e-6, index=1.0, fiber_broken=False):
        """Store the link constants (SI: W, m); ``target`` is a :class:`Target`."""
        if mode_radius_m <= 0 or wavelength_m <= 0 or index <= 0:
            raise ValueError('mode_radius_m, wavelength_m and index must be > 0')
        if source_power_w < 0 or gap_m < 0:
            raise ValueError('source_power_w and gap_m must be >= 0')
        self.target = target
        self.source_power_w = float(source_power_w)
        self.wavelength_m = float(wavelength_m)
        self.mode_radius_m = float(mode_radius_m)
        self.gap_m = float(gap_m)
        self.index = float(index)
        self.fiber_broken = bool(fiber_broken)

    @property
    def curvature_per_m2(self):
        """Return ``1 / (w^2 q)`` (1/m^2): ``ln P = ln P_max - curvature |d|^2``."""
        return 1.0 / (self.mode_radius_m ** 2 * op.rayleigh_factor(
            self.gap_m, self.mode_radius_m, self.wavelength_m, self.index))

    def max_power_w(self):
        """Return the largest coupled power (W), at zero offset."""
        if self.fiber_broken:
            return 0.0
        return self.source_power_w * coupling_efficiency_2d(
            0.0, 0.0, self.gap_m, self.mode_radius_m, self.wavelength_m, self.index)

    def power_w(self, t_s, x_m, y_m):
        """Return the true coupled power (W) with the input core at ``(x_m, y_m)`` at ``t_s``."""
        if self.fiber_broken:
            return 0.0 * np.asarray(x_m, dtype=float) if np.ndim(x_m) else 0.0
        sx, sy = self.target.position(t_s)
        return self.source_power_w * coupling_efficiency_2d(
            np.asarray(x_m) - sx, np.asarray(y_m) - sy, self.gap_m, self.mode_radius_m,
            self.wavelength_m, self.index)

    def loss_db(self, t_s, x_m, y_m):
        """Return the true loss (dB) against the (moving) maximum at ``t_s``."""
        return op.loss_db(self.power_w(t_s, x_m, y_m), self.max_power_w())


class OpticalLink2D:
    """Coupling in two axes plus the 1-D model's :class:`~fiber_align.plant.optics.Detector`."""

    def __init__(self, coupling, detector):
        """Combine a :class:`FiberCoupling2D` and a detector."""
        self.coupling = coupling
        self.detector = detector

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
        if optics_params is None:
            optics_params = load_params(op.CONFIG_FILE, op.CONFIG_NODE)
        if target_params is None:
            target_params = load_params(CONFIG_FILE, CONFIG_NODE)
        o = op._section(optics_params, op.CONFIG_KEY)
        tg = op._section(target_params, 'target')
        for k, v in overrides.items():
            if k in TARGET_KEYS:
                tg[k] = v
            elif k in LINK_KEYS or k in DETECTOR_KEYS:
                o[k] = v
            else:
                raise ValueError('unknown 2-D optics parameter %r (known: %s)'
                                 % (k, ', '.join(TARGET_KEYS + LINK_KEYS + DETECTOR_KEYS)))
        unknown = sorted(set(tg) - set(TARGET_KEYS))
        if unknown:
            raise ValueError('unknown target parameter(s): %s (known: %s)'
                             % (', '.join(unknown), ', '.join(TARGET_KEYS)))
        target = Target(**tg)
        coupling = FiberCoupling2D(target, **{k: o[k] for k in LINK_KEYS if k in o})
        detector = op.Detector(seed=seed, **{k: o[k] for k in DETECTOR_KEYS if k in o})
        return cls(coupling, detector)

    def true_power_w(self, t_s, x_m, y_m):
        """Return the noise-free coupled power (W)."""
        return self.coupling.power_w(t_s, x_m, y_m)

    def measure(self, t_s, x_m, y_m, dt_s=None):
        """Return the detector reading (W) with the core at ``(x_m, y_m)`` (m) at ``t_s``."""
        return self.detector.measure(float(self.coupling.power_w(t_s, x_m, y_m)), dt_s)

    def loss_db(self, t_s, x_m, y_m):
        """Return the true loss (dB) against the (moving) maximum."""
        return self.coupling.loss_db(t_s, x_m, y_m)


def load_optics2d(seed=0, **overrides):
    """Return an :class:`OpticalLink2D` from ``optics.yaml`` and ``optics2d.yaml``."""
    return OpticalLink2D.from_params(None, None, seed=seed, **overrides)
