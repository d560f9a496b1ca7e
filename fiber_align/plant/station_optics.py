# SPDX-License-Identifier: Apache-2.0
"""
A chip between two fibers: the input fiber couples into the waveguide, the output fiber out.

Each fiber rides on an x-y pair of bimorphs (input ``(x_i, y_i)``, output ``(x_o, y_o)``,
m). The power at the output detector is::

    P = P_source * eta(d_i) * T_chip * eta(d_o)

with ``T_chip = 10^(-chip_loss_db / 10)`` and, for each facet, the overlap of the fiber's
Gaussian mode (waist ``w1``, m) with the waveguide's (waist ``w2``, m) at a lateral offset
``d`` (m) (Joyce and DeLoach, Appl. Opt. 23, 4187 (1984); Marcuse, Bell Syst. Tech. J. 56,
703 (1977))::

    eta = (2 w1 w2 / (w1^2 + w2^2))^2 exp(-2 d^2 / (w1^2 + w2^2))

so ``ln P`` is a separable paraboloid in the four coordinates: curvature
``2 / (w1^2 + w2^2)`` (1/m^2) on each side. The facets are butt-coupled (no gap, no tilt).

Each fiber's offset is ``position - facet + cure(t)``: the cure term is the adhesive's pull
on the fiber (:class:`CureDrift`), a slow move of ``amplitude_m`` along ``angle_rad`` over
``duration_s``, raised-cosine in time (no jump in speed at either end).

Constants: the source and the detector of ``config/optics.yaml`` (shared with the one- and
two-axis models, :class:`fiber_align.plant.optics.Detector`); the chip, the facets and the
cure in ``config/station.yaml`` (node ``simulated_station_optics``). SI units.
"""

import math

import numpy as np

from fiber_align.config import load_params
from fiber_align.plant import optics as op

CONFIG_FILE = 'station.yaml'
CONFIG_NODE = 'simulated_station_optics'
SIDES = ('in', 'out')
CHIP_KEYS = ('fiber_mode_field_diameter_m', 'waveguide_mode_field_diameter_m',
             'chip_loss_db', 'facet_in_x_m', 'facet_in_y_m', 'facet_out_x_m', 'facet_out_y_m',
             'cure_in_amplitude_m', 'cure_in_angle_rad', 'cure_in_duration_s',
             'cure_out_amplitude_m', 'cure_out_angle_rad', 'cure_out_duration_s',
             'cure_start_s')
SOURCE_KEYS = ('source_power_w', 'fiber_broken')
DETECTOR_KEYS = ('noise_floor_w', 'rin_db', 'averaging_time_s', 'saturation_w',
                 'sample_period_s')


def mode_overlap(offset_m, w1_m, w2_m):
    """
    Return the power coupling (0..1) of two Gaussian modes of waists ``w1_m``, ``w2_m`` (m).

    :param offset_m: lateral offset of the mode centres (m), scalar or array.
    """
    s = float(w1_m) ** 2 + float(w2_m) ** 2
    d = np.asarray(offset_m, dtype=float)
    out = (2.0 * w1_m * w2_m / s) ** 2 * np.exp(-2.0 * d * d / s)
    return float(out) if out.ndim == 0 else out


def overlap_curvature(w1_m, w2_m):
    """Return ``2 / (w1^2 + w2^2)`` (1/m^2): ``ln eta = ln eta0 - curvature d^2``."""
    return 2.0 / (float(w1_m) ** 2 + float(w2_m) ** 2)


class CureDrift:
    """
    The adhesive's pull on one fiber (m) against time (s).

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


class StationCoupling:
    """Noise-free power (W) at the output detector against time and the four positions."""

    def __init__(self, source_power_w, fiber_mode_field_diameter_m,
                 waveguide_mode_field_diameter_m, chip_loss_db, facets, cures=None,
                 fiber_broken=False):
        """
        Store the link (SI).

        :param facets: ``((x_in, y_in), (x_out, y_out))``: where each fiber's core couples
            best, in its own actuators' coordinates (m).
        :param cures: ``(CureDrift, CureDrift)`` for the input and output fiber, or None.
        """
        if not (fiber_mode_field_diameter_m > 0 and waveguide_mode_field_diameter_m > 0):
            raise ValueError('mode field diameters must be > 0')
        if source_power_w < 0 or chip_loss_db < 0:
            raise ValueError('source_power_w and chip_loss_db must be >= 0')
        self.source_power_w = float(source_power_w)
        self.w_fiber_m = 0.5 * float(fiber_mode_field_diameter_m)
        self.w_guide_m = 0.5 * float(waveguide_mode_field_diameter_m)
        self.chip_loss_db = float(chip_loss_db)
        self.facets = tuple((float(f[0]), float(f[1])) for f in facets)
        self.cures = tuple(cures) if cures is not None else (CureDrift(), CureDrift())
        self.fiber_broken = bool(fiber_broken)

    @property
    def curvature_per_m2(self):
        """Return the curvature of ``ln P`` on each side (1/m^2)."""
        return overlap_curvature(self.w_fiber_m, self.w_guide_m)

    def peak(self, t_s):
        """Return the four coordinates of the true joint peak at ``t_s`` (m)."""
        out = []
        for f, c in zip(self.facets, self.cures):
            dx, dy = c.offset(t_s)
            out += [f[0] - dx, f[1] - dy]
        return tuple(out)

    def max_power_w(self):
        """Return the largest power at the output detector (W), at the joint peak."""
        if self.fiber_broken:
            return 0.0
        eta0 = mode_overlap(0.0, self.w_fiber_m, self.w_guide_m)
        return self.source_power_w * eta0 * eta0 * 10.0 ** (-self.chip_loss_db / 10.0)

    def side_offsets(self, t_s, pos):
        """Return the lateral offsets ``(d_in, d_out)`` (m) of the four positions (m)."""
        pk = self.peak(t_s)
        p = [np.asarray(v, dtype=float) for v in pos]
        return (np.hypot(p[0] - pk[0], p[1] - pk[1]), np.hypot(p[2] - pk[2], p[3] - pk[3]))

    def power_w(self, t_s, pos):
        """Return the true power (W) with the fibers at ``pos = (x_i, y_i, x_o, y_o)`` (m)."""
        if np.ndim(t_s) == 0 and np.ndim(pos[0]) == 0:       # the per-period call
            pk = self.peak(t_s)
            d2 = [(pos[0] - pk[0]) ** 2 + (pos[1] - pk[1]) ** 2,
                  (pos[2] - pk[2]) ** 2 + (pos[3] - pk[3]) ** 2]
            if self.fiber_broken:
                return 0.0
            s = self.w_fiber_m ** 2 + self.w_guide_m ** 2
            return self.max_power_w() * math.exp(-2.0 * (d2[0] + d2[1]) / s)
        d_in, d_out = self.side_offsets(t_s, pos)
        out = (self.source_power_w * 10.0 ** (-self.chip_loss_db / 10.0)
               * mode_overlap(d_in, self.w_fiber_m, self.w_guide_m)
               * mode_overlap(d_out, self.w_fiber_m, self.w_guide_m))
        out = np.asarray(out) * (0.0 if self.fiber_broken else 1.0)
        return float(out) if out.ndim == 0 else out

    def loss_db(self, t_s, pos):
        """Return the true loss (dB) against the joint peak at ``t_s``."""
        return op.loss_db(self.power_w(t_s, pos), self.max_power_w())


class StationLink:
    """The coupling plus the detector of :mod:`fiber_align.plant.optics`."""

    def __init__(self, coupling, detector):
        """Combine a :class:`StationCoupling` and a :class:`~fiber_align.plant.optics.Detector`."""
        self.coupling = coupling
        self.detector = detector

    @classmethod
    def from_params(cls, optics_params=None, station_params=None, seed=0, **overrides):
        """
        Build a link; ``overrides`` replace keys of either mapping.

        :param optics_params: the ``optics`` mapping of ``config/optics.yaml`` (None: load);
            only its source and detector keys are used.
        :param station_params: node ``simulated_station_optics`` of ``config/station.yaml``
            (None: load).
        :param seed: detector noise seed.
        """
        if optics_params is None:
            optics_params = load_params(op.CONFIG_FILE, op.CONFIG_NODE)
        if station_params is None:
            station_params = load_params(CONFIG_FILE, CONFIG_NODE)
        o = op._section(optics_params, op.CONFIG_KEY)
        # the node's detector seed is the ``seed`` argument, not a chip key
        c = {k: v for k, v in station_params.items() if k != 'seed'}
        for k, v in overrides.items():
            if k in CHIP_KEYS:
                c[k] = v
            elif k in SOURCE_KEYS or k in DETECTOR_KEYS:
                o[k] = v
            else:
                raise ValueError('unknown station optics parameter %r (known: %s)'
                                 % (k, ', '.join(CHIP_KEYS + SOURCE_KEYS + DETECTOR_KEYS)))
        missing = sorted(set(CHIP_KEYS) - set(c))
        unknown = sorted(set(c) - set(CHIP_KEYS))
        if missing or unknown:
            raise ValueError('station optics parameters: missing %s, unknown %s'
                             % (missing or 'none', unknown or 'none'))
        cures = tuple(CureDrift(c['cure_%s_amplitude_m' % s], c['cure_%s_angle_rad' % s],
                                c['cure_%s_duration_s' % s], c['cure_start_s'])
                      for s in SIDES)
        coupling = StationCoupling(
            o['source_power_w'], c['fiber_mode_field_diameter_m'],
            c['waveguide_mode_field_diameter_m'], c['chip_loss_db'],
            ((c['facet_in_x_m'], c['facet_in_y_m']), (c['facet_out_x_m'], c['facet_out_y_m'])),
            cures, bool(o.get('fiber_broken', False)))
        detector = op.Detector(seed=seed, **{k: o[k] for k in DETECTOR_KEYS if k in o})
        return cls(coupling, detector)

    def measure(self, t_s, pos, dt_s=None):
        """Return the detector reading (W) with the fibers at ``pos`` (4 values, m)."""
        return self.detector.measure(float(self.coupling.power_w(t_s, pos)), dt_s)

    def loss_db(self, t_s, pos):
        """Return the true loss (dB) against the joint peak."""
        return self.coupling.loss_db(t_s, pos)
