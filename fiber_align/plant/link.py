# SPDX-License-Identifier: Apache-2.0
"""
One optical link for any number of axes: facets of Gaussian overlaps against moving targets.

A link carries the source power ``P_source`` (W) through a list of facets and a transmission
``T`` (the chip's loss; 1 for a fiber-to-fiber link). Each facet joins two Gaussian modes of
waists ``w1``, ``w2`` (m) across a gap ``z`` (m) in a medium of index ``n`` at the vacuum
wavelength ``lambda`` (m); its lateral offset ``d`` (m) is the vector of its axes' positions
minus its target (where it couples best, moving in time). The overlap of the two modes is
(Joyce and DeLoach, Appl. Opt. 23, 4187 (1984))::

    eta(d) = eta0 exp(-c |d|^2)
    eta0 = 4 / ((w1 / w2 + w2 / w1)^2 + (lambda z / (pi n w1 w2))^2)
    c = 2 (w1^2 + w2^2) / ((w1^2 + w2^2)^2 + (lambda z / (pi n))^2)

(equal waists ``w``: ``eta0 = 1 / q``, ``c = 1 / (w^2 q)``, ``q = 1 + (lambda z / (2 pi n
w^2))^2``, the fiber-to-fiber model of :mod:`fiber_align.plant.optics`; no gap: ``eta0 =
(2 w1 w2 / (w1^2 + w2^2))^2``, ``c = 2 / (w1^2 + w2^2)``). The power is::

    P = P_source T prod_f eta_f(d_f) = P_max exp(-sum_f c_f |d_f|^2)

so ``ln P`` is a separable paraboloid in all the axes, which the peak fits exploit.

A target is a start, a drift velocity, a vibration along one direction, and an optional pull
(:class:`CureDrift`, the adhesive's pull on a fiber while it cures) that moves the best point
the other way. What each machine sets (the axes of a facet, the modes, the target motion,
the cure) is data: :mod:`fiber_align.plant.optics2d` (one facet of two axes against a moving
target) and :mod:`fiber_align.plant.station_optics` (two facets of two axes and a chip).
SI units throughout.
"""

import math

import numpy as np

from fiber_align.config import load_params
from fiber_align.plant import optics as op

DETECTOR_KEYS = ('noise_floor_w', 'rin_db', 'averaging_time_s', 'saturation_w',
                 'sample_period_s', 'floor_w', 'quantum_w')


def overlap(w1_m, w2_m, gap_m=0.0, wavelength_m=1.55e-6, index=1.0):
    """Return the aligned overlap ``eta0`` (0..1) and its curvature ``c`` (1/m^2) as a pair."""
    if not (w1_m > 0 and w2_m > 0 and wavelength_m > 0 and index > 0):
        raise ValueError('mode waists, wavelength_m and index must be > 0')
    if gap_m < 0:
        raise ValueError('gap_m must be >= 0')
    w1, w2 = float(w1_m), float(w2_m)
    s = w1 * w1 + w2 * w2
    g = float(wavelength_m) * float(gap_m) / (math.pi * float(index))
    eta0 = 4.0 / ((w1 / w2 + w2 / w1) ** 2 + (g / (w1 * w2)) ** 2)
    return eta0, 2.0 * s / (s * s + g * g)


class CureDrift:
    """
    The adhesive's pull on one fiber (m) against time (s), in the plane of its two axes.

    ``amplitude_m (1 - cos(pi u)) / 2`` along ``angle_rad``, ``u = (t - start) / duration``
    clipped to 0..1: at rest before ``start_s``, the full pull after ``start_s + duration_s``.
    """

    def __init__(self, amplitude_m=0.0, angle_rad=0.0, duration_s=1.0, start_s=0.0):
        """Store the pull (m), its direction (rad), duration (s) and start (s)."""
        if not duration_s > 0:
            raise ValueError('cure duration_s must be > 0, got %r' % duration_s)
        self.amplitude_m = float(amplitude_m)
        self.angle_rad = float(angle_rad)
        self.duration_s = float(duration_s)
        self.start_s = float(start_s)

    def offset(self, t_s):
        """Return the pull ``(dx, dy)`` (m) at ``t_s`` (s); scalars or arrays."""
        if np.ndim(t_s) == 0:            # the per-period call: scalar math
            if not self.amplitude_m or t_s <= self.start_s:
                return 0.0, 0.0
            u = min(1.0, (float(t_s) - self.start_s) / self.duration_s)
            a = self.amplitude_m * 0.5 * (1.0 - math.cos(math.pi * u))
            return a * math.cos(self.angle_rad), a * math.sin(self.angle_rad)
        u = np.clip((np.asarray(t_s, dtype=float) - self.start_s) / self.duration_s, 0.0, 1.0)
        a = self.amplitude_m * 0.5 * (1.0 - np.cos(math.pi * u))
        return a * math.cos(self.angle_rad), a * math.sin(self.angle_rad)


class Target:
    """
    Where a facet couples best (m, one value per axis) against time (s).

    ``s(t) = s0 + v t + a u sin(2 pi f t) - pull(t)``: ``s0`` the start (m), ``v`` the drift
    velocity (m/s), ``a`` the vibration amplitude (m) at ``f`` (Hz) along the unit vector
    ``u``, ``pull`` an object with ``offset(t) -> per-axis m`` (e.g. :class:`CureDrift`).
    """

    def __init__(self, position_m, drift_m_per_s=None, vibration_amplitude_m=0.0,
                 vibration_frequency_hz=0.0, vibration_direction=None, pull=None):
        """Store the motion (SI); ``None`` drift is at rest, ``None`` direction the 1st axis."""
        self.p0 = tuple(float(v) for v in position_m)
        n = len(self.p0)
        self.v = tuple(float(v) for v in (drift_m_per_s or (0.0,) * n))
        self.amp = float(vibration_amplitude_m)
        self.freq = float(vibration_frequency_hz)
        self.u = tuple(float(v) for v in (vibration_direction or (1.0,) + (0.0,) * (n - 1)))
        self.pull = pull

    def position(self, t_s):
        """Return the best point (m) at ``t_s`` (s): a tuple of floats, or of arrays."""
        scalar = isinstance(t_s, (float, int))      # the per-period call: scalar math
        t = float(t_s) if scalar else np.asarray(t_s, dtype=float)
        out = [p + v * t for p, v in zip(self.p0, self.v)]
        if self.amp:
            s = self.amp * (math.sin if scalar else np.sin)(2.0 * math.pi * self.freq * t)
            out = [x + s * u for x, u in zip(out, self.u)]
        if self.pull is not None:
            out = [x - d for x, d in zip(out, self.pull.offset(t_s))]
        if scalar or t.ndim == 0:
            return tuple(float(x) for x in out)
        return tuple(out)


class Facet:
    """One Gaussian overlap: the axes it spans (indices of the link's positions), its target."""

    def __init__(self, axes, target, w1_m, w2_m, gap_m=0.0, wavelength_m=1.55e-6, index=1.0):
        """Store the facet (SI); see :func:`overlap` for the modes and the gap."""
        self.axes = tuple(int(a) for a in axes)
        if len(target.p0) != len(self.axes):
            raise ValueError('a target of %d axes for a facet of %d'
                             % (len(target.p0), len(self.axes)))
        self.target = target
        self.eta0, self.curvature_per_m2 = overlap(w1_m, w2_m, gap_m, wavelength_m, index)


class Coupling:
    """Noise-free power (W) at the detector against time (s) and the axes' positions (m)."""

    def __init__(self, source_power_w, facets, transmission=1.0, fiber_broken=False):
        """Store the link: ``source_power_w`` (W), the facets, the transmission ``T`` (0..1)."""
        if source_power_w < 0 or not 0.0 <= transmission <= 1.0:
            raise ValueError('source_power_w must be >= 0 and transmission in 0..1')
        self.source_power_w = float(source_power_w)
        self.facets = tuple(facets)
        self.transmission = float(transmission)
        self.fiber_broken = bool(fiber_broken)
        self.n_axes = 1 + max(a for f in self.facets for a in f.axes)

    def peak(self, t_s):
        """Return the best position of every axis (m) at ``t_s`` (s)."""
        out = [0.0] * self.n_axes
        for f in self.facets:
            for a, v in zip(f.axes, f.target.position(t_s)):
                out[a] = v
        return tuple(out)

    def max_power_w(self):
        """Return the largest power (W), at the joint peak (0 with a broken fiber)."""
        if self.fiber_broken:
            return 0.0
        out = self.source_power_w * self.transmission
        for f in self.facets:
            out *= f.eta0
        return out

    def power_at(self, t_s, positions):
        """Return the true power (W) with the axes at ``positions`` (m; scalars or arrays)."""
        if isinstance(t_s, (float, int)) and all(isinstance(p, (float, int))
                                                 for p in positions):
            return self._power_scalar(t_s, positions)
        scalar = np.ndim(t_s) == 0 and all(np.ndim(p) == 0 for p in positions)
        if not scalar:
            positions = [np.asarray(p, dtype=float) for p in positions]
        pk = self.peak(t_s)
        e = 0.0
        for f in self.facets:
            d2 = sum((positions[a] - pk[a]) ** 2 for a in f.axes)
            e = e + f.curvature_per_m2 * d2
        if scalar:                       # the per-period call: scalar math
            return self.max_power_w() * math.exp(-e)
        return self.max_power_w() * np.exp(-np.asarray(e, dtype=float))

    def _power_scalar(self, t_s, positions):
        """:meth:`power_at` of floats: the per-period call, in scalar math (docs/benchmarks.md)."""
        pk = self.peak(t_s)
        e = 0.0
        for f in self.facets:
            d2 = 0.0
            for a in f.axes:
                d2 += (positions[a] - pk[a]) ** 2
            e += f.curvature_per_m2 * d2
        return self.max_power_w() * math.exp(-e)

    def loss_at(self, t_s, positions):
        """Return the true loss (dB) against the joint peak at ``t_s``."""
        return op.loss_db(self.power_at(t_s, positions), self.max_power_w())

    power_w = power_at       # a machine's coupling may name its axes in these two
    loss_db = loss_at


class Link:
    """A :class:`Coupling` and the :class:`~fiber_align.plant.optics.Detector` behind it."""

    def __init__(self, coupling, detector):
        """Combine the coupling and the detector."""
        self.coupling = coupling
        self.detector = detector

    def true_power_w(self, t_s, positions):
        """Return the noise-free power (W)."""
        return self.coupling.power_at(t_s, positions)

    def measure(self, t_s, positions, dt_s=None):
        """Return the detector reading (W) with the axes at ``positions`` (m) at ``t_s``."""
        return self.detector.measure(float(self.coupling.power_at(t_s, positions)), dt_s)

    def loss_db(self, t_s, positions):
        """Return the true loss (dB) against the (moving) joint peak."""
        return self.coupling.loss_at(t_s, positions)


def sections(optics_params, params, config_file, config_node, key=None):
    """
    Return the ``optics`` mapping of ``optics.yaml`` and a machine's mapping (flat, SI).

    :param optics_params: the ``optics`` mapping (None: load ``config/optics.yaml``).
    :param params: the machine's node mapping (None: load ``config_file``, ``config_node``).
    :param key: the machine's keys are nested under it (None: the node's own keys, but its
        detector ``seed``, which is the link's ``seed`` argument).
    """
    if optics_params is None:
        optics_params = load_params(op.CONFIG_FILE, op.CONFIG_NODE)
    if params is None:
        params = load_params(config_file, config_node)
    if key is not None:
        return op._section(optics_params, op.CONFIG_KEY), op._section(params, key)
    return (op._section(optics_params, op.CONFIG_KEY),
            {k: v for k, v in params.items() if k != 'seed'})


def split_overrides(overrides, groups, what):
    """
    Sort ``overrides`` into the mappings of ``groups``: ``((keys, mapping), ...)``.

    A key goes into the first group that lists it; an unknown key is a ``ValueError``
    naming ``what`` (e.g. ``'2-D optics'``) and the known keys.
    """
    for k, v in overrides.items():
        for keys, mapping in groups:
            if k in keys:
                mapping[k] = v
                break
        else:
            known = [key for keys, _ in groups for key in keys]
            raise ValueError('unknown %s parameter %r (known: %s)'
                             % (what, k, ', '.join(known)))


def detector(optics, seed):
    """Return the :class:`~fiber_align.plant.optics.Detector` of an ``optics`` mapping."""
    return op.Detector(seed=seed, **{k: optics[k] for k in DETECTOR_KEYS if k in optics})
