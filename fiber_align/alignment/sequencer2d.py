# SPDX-License-Identifier: Apache-2.0
"""
Two-axis alignment sequencer: a pure, step-based state machine for an x-y pair of bimorphs.

Once per control period the loop (offline, or a ROS node) calls
``seq.update(t_s, x_m, y_m, power_w)`` with both measured displacements (m) and the
detector reading (W) and gets the two setpoints ``(x_m, y_m)`` back. Commands ``align()``,
``release()`` and ``switch(on)`` return ``(ok, message)``; ``state``, ``fault_reason`` and
``status()`` tell where it is. States as in the 1-D :mod:`~fiber_align.alignment.sequencer`::

    IDLE -> SEARCHING -> PEAKING -> TRACKING      (align)
    any  -> RELEASING -> IDLE                     (release, switch(False))
    IDLE -> PEAKING (re-peak) -> TRACKING         (switch(True): the last aligned point)
    active -> HELD -> SEARCHING / PEAKING (re-peak) (a driver held its output, then back)
    any active state -> FAULT (reason)

SEARCHING
    Measures the floor at rest, sets the threshold ``threshold_sigma`` standard deviations
    above its mean, then walks to the centre of the reachable square and out along an
    Archimedean spiral (:func:`~fiber_align.alignment.search2d.spiral_pitch`) until
    ``confirm_samples`` readings in a row are above the threshold.
PEAKING
    Reads a cross of five settled points around the best point, fits ``ln P`` with a
    circular paraboloid (the Gaussian overlap makes it exact), moves the cross to the vertex
    and repeats until the vertex lies within ``converge_tolerance_m`` of the cross centre;
    then moves to the vertex and checks the reading against the fit.
HELD, TRACKING
    Every machine's (:mod:`~fiber_align.alignment.hold`,
    :mod:`~fiber_align.alignment.tracking`); the dither a circle of ``dither_radius_m``
    at ``dither_frequency_hz``.

All quantities are SI (s, m, W); dB only for ratios. Defaults: ``config/sequencer2d.yaml``.
"""

import numpy as np

from fiber_align.alignment import search2d as s2
from fiber_align.alignment.driver_state import DriverState
from fiber_align.alignment.machine import check_params, Machine
from fiber_align.alignment.multiaxis import MultiAxis, PATH_RATE_SHARE  # noqa: F401
from fiber_align.alignment.peak2d import AXES, PeakFitMixin
from fiber_align.alignment.states import (ACTIVE, dbm, FAULT, HELD, IDLE,  # noqa: F401
                                          PEAKING, RELEASING, SEARCHING, STATES,
                                          TRACKING)
from fiber_align.config import load_params

CONFIG_FILE = 'sequencer2d.yaml'
CONFIG_NODE = 'alignment_sequencer_2d'
#: The drivers of the two axes, as :attr:`Sequencer2D.drivers` names them.
DRIVERS = tuple('%s/actuator_driver' % a for a in AXES)


def load_sequencer2d_params(path=CONFIG_FILE, node=CONFIG_NODE, **overrides):
    """Return the parameters of ``node`` in a params file, ``overrides`` applied."""
    return dict(load_params(path, node), **overrides)


class Sequencer2D(MultiAxis, Machine, PeakFitMixin):
    """Find, peak, track and switch the light in x and y (see the module docstring)."""

    CREST = False
    SEARCH_PHASE = 'spiral'
    RESUMES_SEARCH = True
    DITHERS = (('dither_frequency_hz', (0, 1)),)
    AXIS_NAMES = AXES

    def __init__(self, params=None, period_s=None, path_rate_m_per_s=None, **overrides):
        """
        Build from a parameter mapping (``None``: ``config/sequencer2d.yaml``).

        :param period_s: period of the :meth:`update` calls (s): 1 / the graph's
            ``rate_hz`` (required: the core reads no file to find it).
        :param path_rate_m_per_s: the fastest the realtime loop follows a setpoint (m/s,
            the graph's ``realtime_setpoint_rate_m_per_s``); the search walks at most
            :data:`PATH_RATE_SHARE` of it, so the actuators keep up with the spiral (a
            walk faster than its path lags further each period until the follow check
            faults). ``None`` or <= 0: no bound (offline, lockstep).

        Every key of the file's ``alignment_sequencer_2d`` node is required (the file is
        the one source of defaults); ``overrides`` replace keys.
        """
        p = check_params(load_params(CONFIG_FILE, CONFIG_NODE), params, overrides,
                         'sequencer2d')
        for a in AXES:
            if not p['range_%s_max_m' % a] > p['range_%s_min_m' % a]:
                raise ValueError('range_%s_max_m must exceed range_%s_min_m' % (a, a))
        self.drivers = DriverState(DRIVERS)
        self.curvature_per_m2 = None
        self._init_axes(p, [p['park_x_m'], p['park_y_m']],
                        [p['range_x_min_m'], p['range_y_min_m']],
                        [p['range_x_max_m'], p['range_y_max_m']], period_s, path_rate_m_per_s)
        self.capture_radius_m = s2.capture_radius(p['mode_radius_m'], p['spiral_capture_db'])
        self.pitch_m = s2.spiral_pitch(p['mode_radius_m'], p['spiral_capture_db'],
                                       self.confirm_chord_m)
        self.curvature_prior = 1.0 / p['mode_radius_m'] ** 2

    # ---- commands (Machine: align, release, switch) ----------------------------------
    def _no_light_text(self):
        return ('no light found anywhere in the reachable square x %.1f..%.1f um, y %.1f..%.1f '
                'um (threshold %.1f dBm): broken fiber, no source, or the target is out of '
                'reach' % (self.lo[0] * 1e6, self.hi[0] * 1e6, self.lo[1] * 1e6,
                           self.hi[1] * 1e6, dbm(self.threshold_w)))

    def _hold_center(self):
        """Return what a re-peak after a HELD starts from: the last aligned point, or None."""
        return None if self.state == SEARCHING or self.aligned is None else self.aligned

    def search_path(self, start):
        """
        Return the first-light walk from ``start`` (m): the square's centre, then outwards.

        It ends half a pitch beyond the half-diagonal, so that in every direction an arm
        passes within half a pitch of the corners (the setpoints are clipped to the square,
        so the outer turn runs along its edges).
        """
        center = 0.5 * (self.lo + self.hi)
        r_max = 0.5 * float(np.hypot(*(self.hi - self.lo))) + 0.5 * self.pitch_m
        return s2.SpiralPath(start, center, self.pitch_m, r_max)

    # ---- the control-period step ----------------------------------------------------
    def update(self, t_s, x_m, y_m, power_w, driver_active=None):
        """
        Advance one control period; return the setpoints ``(x_m, y_m)`` (m).

        :param t_s: time of the readings (s).
        :param x_m: measured x displacement (m), or ``None`` if none arrived.
        :param y_m: measured y displacement (m), or ``None`` if none arrived.
        :param power_w: optical power reading (W), or ``None`` if none arrived.
        :param driver_active: ``False`` when the drivers are not driving (a bool, or one
            per axis); ``None``: as :attr:`drivers` says (what the drivers published).
        """
        return self._update(t_s, (x_m, y_m), power_w, driver_active)

    def status(self):
        """Return a dict describing the state (for topics, diagnostics and reports; SI)."""
        al = self.aligned
        return dict(state=self.state, phase=self._phase, fault_reason=self.fault_reason,
                    setpoint_x_m=float(self.sp[0]), setpoint_y_m=float(self.sp[1]),
                    aligned_x_m=None if al is None else float(al[0]),
                    aligned_y_m=None if al is None else float(al[1]),
                    threshold_w=self.threshold_w, peak_samples=self.peak_samples,
                    search_samples=self.search_samples, iterations=self.iterations,
                    **({'hold_reason': self.hold_reason} if self.state == HELD else {}))
