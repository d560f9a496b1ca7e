# SPDX-License-Identifier: Apache-2.0
"""
The coupled station's sequencer: input and output fiber aligned through a chip at once.

A pure, step-based state machine for four axes ``(x_in, y_in, x_out, y_out)`` (m). Once per
control period the loop calls ``seq.update(t_s, positions_m, power_w)`` with the four
measured displacements (m) and the output detector's reading (W) and gets the four
setpoints back. Commands and states are those of :class:`~fiber_align.alignment.machine.
Machine` (``align``, ``release``, ``switch``; IDLE, SEARCHING, PEAKING, TRACKING,
RELEASING, FAULT), and HELD while a driver holds its output: all four setpoints held
(:mod:`~fiber_align.alignment.hold`, the rule of every sequencer); back at them, a re-peak
around the last estimate, or the search again (held while searching, or no light there).

SEARCHING
    Floor at rest, threshold ``threshold_sigma`` above it; then the input fiber visits the
    points of a square grid around its nominal position and at each the output fiber
    rasters its own square (:func:`~fiber_align.alignment.station_search.search_design`:
    light reaches the detector only when both sides are roughly in line) until
    ``confirm_samples`` readings are above the threshold; the walk goes on to the pass's
    brightest reading (at most ``crest_max_samples``), where PEAKING starts. The walk done
    without light is a FAULT that says so.
PEAKING
    :class:`~fiber_align.alignment.station_peak.JointPeakMixin`: both sides in one fit.
TRACKING
    A circular dither of ``dither_radius_m`` on each side, at ``dither_in_frequency_hz``
    and ``dither_out_frequency_hz``; one regression of ``ln P`` on the four measured
    displacements (:class:`~fiber_align.alignment.tracking.JointDemodulator`) gives
    both sides' gradients; each side's estimate moves at ``bandwidth * g / (2 k)`` with its
    own curvature ``k``: a loop of bandwidth ``tracking_bandwidth_rad_s`` on every axis.

Defaults: node ``station_sequencer`` of ``config/station.yaml``. SI units (s, m, W).
"""

import numpy as np

from fiber_align.alignment import station_search as ss
from fiber_align.alignment.driver_state import DriverState
from fiber_align.alignment.machine import check_params, Machine
from fiber_align.alignment.multiaxis import MultiAxis
from fiber_align.alignment.states import dbm, PEAKING, TRACKING
from fiber_align.alignment.station_peak import AXES4, JointPeakMixin
from fiber_align.config import load_params

CONFIG_FILE = 'station.yaml'
CONFIG_NODE = 'station_sequencer'
NOMINAL_KEYS = ('nominal_in_x_m', 'nominal_in_y_m', 'nominal_out_x_m', 'nominal_out_y_m')


#: The drivers of the four axes, as :attr:`Station.drivers` names them (the station
#: graph's ``in/x`` ... ``out/y`` namespaces).
DRIVERS = tuple('%s/%s/actuator_driver' % (side, a) for side in ('in', 'out')
                for a in ('x', 'y'))


class Station(MultiAxis, Machine, JointPeakMixin):
    """Find, peak and track both fibers of the station (see the module docstring)."""

    CREST = True
    SEARCH_PHASE = 'search'
    DITHERS = (('dither_in_frequency_hz', (0, 1)), ('dither_out_frequency_hz', (2, 3)))
    AXIS_NAMES = AXES4

    method = 'concurrent'

    def __init__(self, params=None, period_s=None, path_rate_m_per_s=None, **overrides):
        """
        Build from a parameter mapping (None: ``config/station.yaml``); every key required.

        :param period_s: period of the :meth:`update` calls (s): 1 / the graph's
            ``rate_hz`` (required).
        :param path_rate_m_per_s: the fastest the realtime loop follows a setpoint (m/s);
            the search walks at most ``multiaxis.PATH_RATE_SHARE`` of it.
            None or <= 0: no bound (offline, lockstep).
        """
        p = check_params(load_params(CONFIG_FILE, CONFIG_NODE), params, overrides,
                         'station')
        #: what the four drivers published (the commands' refusals read it)
        self.drivers = DriverState(DRIVERS)
        if not p['range_max_m'] > p['range_min_m']:
            raise ValueError('range_max_m must exceed range_min_m')
        if p['dither_in_frequency_hz'] == p['dither_out_frequency_hz']:
            raise ValueError('the two dithers need distinct frequencies')
        self.curvatures_per_m2 = None
        self._history = []
        self._init_axes(p, [p[k] for k in NOMINAL_KEYS], np.full(4, float(p['range_min_m'])),
                        np.full(4, float(p['range_max_m'])), period_s, path_rate_m_per_s)
        self.grid_n, self.lines_m = ss.search_design(
            p['coupling_radius_m'], p['search_capture_db'], p['search_slow_share'],
            self.confirm_chord_m, p['search_half_width_m'])
        self.curvature_prior = 1.0 / p['coupling_radius_m'] ** 2

    # ---- commands (Machine) --------------------------------------------------------
    def _curvatures(self):
        """Return ``k`` per axis (1/m^2): each side's fitted one, or the prior."""
        k = self.curvatures_per_m2 or (self.curvature_prior, self.curvature_prior)
        return [k[0], k[0], k[1], k[1]]

    def _hold_center(self):
        """Return the estimate a re-peak after a HELD starts from (m), or None (no light)."""
        center = getattr(self, '_center', None)      # the joint pattern's (serial: None)
        if self.state == PEAKING and center is not None and len(center) == 4:
            return np.array(center, dtype=float)
        return np.array(self.aligned, dtype=float) if self.state in (PEAKING, TRACKING) else None

    def _no_light_text(self):
        c, h = self.park * 1e6, self.p['search_half_width_m'] * 1e6
        return ('no light found with the input fiber anywhere within %.1f um of (%.1f, %.1f) '
                'um and the output fiber within %.1f um of (%.1f, %.1f) um on each axis '
                '(threshold %.1f dBm): broken fiber or chip, no source, or a facet out of '
                'the search square' % (h, c[0], c[1], h, c[2], c[3], dbm(self.threshold_w)))

    def search_path(self, start):
        """Return the first-light walk (:class:`~station_search.Polyline`) from ``start``."""
        p = self.p
        v = ss.search_vertices(start, self.park[:2], self.park[2:], p['search_half_width_m'],
                               self.grid_n, self.lines_m, self.lo, self.hi)
        return ss.Polyline(v)
