# SPDX-License-Identifier: Apache-2.0
"""
A chip between two fibers: the input fiber couples into the waveguide, the output fiber out.

The station's link in :mod:`fiber_align.plant.link` terms: two facets of two axes each
(input ``(x_i, y_i)``, output ``(x_o, y_o)``, m) and the chip's transmission. The power at
the output detector is::

    P = P_source * eta(d_i) * T_chip * eta(d_o)

with ``T_chip = 10^(-chip_loss_db / 10)`` and, for each facet, the overlap of the fiber's
Gaussian mode (waist ``w1``, m) with the waveguide's (waist ``w2``, m) at a lateral offset
``d`` (m) (Joyce and DeLoach, Appl. Opt. 23, 4187 (1984); Marcuse, Bell Syst. Tech. J. 56,
703 (1977))::

    eta = (2 w1 w2 / (w1^2 + w2^2))^2 exp(-2 d^2 / (w1^2 + w2^2))

so ``ln P`` is a separable paraboloid in the four coordinates: curvature
``2 / (w1^2 + w2^2)`` (1/m^2) on each side. The facets are butt-coupled (no gap, no tilt).

Each fiber's offset is ``position - facet + cure(t)``: the cure term is the adhesive's pull
on the fiber (:class:`~fiber_align.plant.link.CureDrift`), a slow move of ``amplitude_m``
along ``angle_rad`` over ``duration_s``, raised-cosine in time (no jump in speed at either
end).

Constants: the source and the detector of ``config/optics.yaml`` (shared with the one- and
two-axis models, :class:`fiber_align.plant.optics.Detector`); the chip, the facets and the
cure in ``config/station.yaml`` (node ``simulated_station_optics``). SI units.
"""

import numpy as np

from fiber_align.plant import link as ln
from fiber_align.plant.link import CureDrift

CONFIG_FILE = 'station.yaml'
CONFIG_NODE = 'simulated_station_optics'
SIDES = ('in', 'out')
CHIP_KEYS = ('fiber_mode_field_diameter_m', 'waveguide_mode_field_diameter_m',
             'chip_loss_db', 'facet_in_x_m', 'facet_in_y_m', 'facet_out_x_m', 'facet_out_y_m',
             'cure_in_amplitude_m', 'cure_in_angle_rad', 'cure_in_duration_s',
             'cure_out_amplitude_m', 'cure_out_angle_rad', 'cure_out_duration_s',
             'cure_start_s')
SOURCE_KEYS = ('source_power_w', 'fiber_broken')
DETECTOR_KEYS = ln.DETECTOR_KEYS
__all__ = ['CureDrift', 'StationCoupling', 'StationLink', 'mode_overlap', 'overlap_curvature']


def mode_overlap(offset_m, w1_m, w2_m):
    """
    Return the power coupling (0..1) of two Gaussian modes of waists ``w1_m``, ``w2_m`` (m).

    :param offset_m: lateral offset of the mode centres (m), scalar or array.
    """
    eta0, c = ln.overlap(w1_m, w2_m)
    d = np.asarray(offset_m, dtype=float)
    out = eta0 * np.exp(-c * d * d)
    return float(out) if out.ndim == 0 else out


def overlap_curvature(w1_m, w2_m):
    """Return ``2 / (w1^2 + w2^2)`` (1/m^2): ``ln eta = ln eta0 - curvature d^2``."""
    return ln.overlap(w1_m, w2_m)[1]


class StationCoupling(ln.Coupling):
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
        if chip_loss_db < 0:
            raise ValueError('chip_loss_db must be >= 0')
        self.w_fiber_m = 0.5 * float(fiber_mode_field_diameter_m)
        self.w_guide_m = 0.5 * float(waveguide_mode_field_diameter_m)
        self.chip_loss_db = float(chip_loss_db)
        cures = tuple(cures) if cures is not None else (CureDrift(), CureDrift())
        sides = [ln.Facet((2 * i, 2 * i + 1), ln.Target(f, pull=c), self.w_fiber_m,
                          self.w_guide_m) for i, (f, c) in enumerate(zip(facets, cures))]
        super().__init__(source_power_w, sides, 10.0 ** (-self.chip_loss_db / 10.0),
                         fiber_broken)
        self.curvature_per_m2 = sides[0].curvature_per_m2

    @property
    def cures(self):
        """Return the pulls on the input and output fiber (:class:`CureDrift`)."""
        return tuple(f.target.pull for f in self.facets)

    @cures.setter
    def cures(self, cures):
        """Set the pulls on the input and output fiber (:class:`CureDrift`)."""
        for f, c in zip(self.facets, cures):
            f.target.pull = c


class StationLink(ln.Link):
    """The coupling plus the detector of :mod:`fiber_align.plant.optics`."""

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
        o, c = ln.sections(optics_params, station_params, CONFIG_FILE, CONFIG_NODE)
        ln.split_overrides(overrides, ((CHIP_KEYS, c), (SOURCE_KEYS + DETECTOR_KEYS, o)),
                           'station optics')
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
            [(c['facet_%s_x_m' % s], c['facet_%s_y_m' % s]) for s in SIDES],
            cures, bool(o.get('fiber_broken', False)))
        return cls(coupling, ln.detector(o, seed))
