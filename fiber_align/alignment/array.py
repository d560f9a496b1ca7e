# SPDX-License-Identifier: Apache-2.0
"""
The fiber array's sequencer: x, y and roll found and peaked at once on the outer channels.

A pure, step-based state machine for three actuators ``(x, y_left, y_right)`` (m; the two
y ones ``roll_arm_m`` apart, :mod:`fiber_align.plant.array_optics`). Once per control
period the loop calls ``seq.update(t_s, positions_m, powers_w)`` with the three measured
displacements (m) and the readings of the two outer channels ``(P_1, P_N)`` (W) and gets
the three setpoints back. Commands, states, HELD and faults are those of every machine
(:class:`~fiber_align.alignment.machine.Machine`, :class:`~fiber_align.alignment.
multiaxis.MultiAxis`); what is the array's own:

Coordinates
    The outer channels' positions ``(x, y_1, y_N)`` (m), ``y_i = y + u_i sin(roll)``: in
    them ``ln P_1`` is a circular paraboloid in ``(x, y_1)`` alone and ``ln P_N`` in ``(x,
    y_N)`` alone (curvature ``1 / coupling_radius_m^2``), whatever the roll. The map to the
    actuators and back is exact (:meth:`ArrayMachine.to_channels`, :meth:`~ArrayMachine.
    to_actuators`); the patterns are set and the readings fitted in these coordinates.
SEARCHING
    Floor at rest, threshold; then a raster in x and y at roll 0 over the stroke, its
    lines as far apart as the capture allows (:func:`~fiber_align.alignment.search2d.
    spiral_pitch`), until the brighter outer channel reads above the threshold; on to the
    pass's brightest reading.
PEAKING
    One pattern: the centre and one point ``h`` along each of ``x``, ``y_1``, ``y_N`` (the
    sign alternating), settled (:class:`~fiber_align.alignment.visit.Visit`): each channel
    sees three distinct points of its own plane, which fix its paraboloid with the known
    curvature (a Newton step: the Gaussian overlap is exact). The new centre is the joint
    vertex, the maximum of ``ln P_1 + ln P_N``: ``x`` midway between the two channels'
    vertices, ``y_1`` and ``y_N`` at theirs (a channel still dark moves rigidly with the
    other). Converged when the step is within ``converge_tolerance_m``; a reading at the
    vertex verifies both channels' predicted powers.
TRACKING
    A sine of ``dither_radius_m`` on each actuator at its own frequency; one regression of
    the channels' mean ``ln P`` (:class:`~fiber_align.alignment.tracking.Tracker`).

Defaults: node ``array_sequencer`` of ``config/array.yaml``; the geometry (``channels``,
``pitch_m``, ``roll_arm_m``) from node ``simulated_array_optics`` there. SI (s, m, W, rad).
"""

import math

import numpy as np

from fiber_align.alignment import search2d as s2
from fiber_align.alignment import station_search as ss
from fiber_align.alignment.driver_state import DriverState
from fiber_align.alignment.machine import check_params, Machine
from fiber_align.alignment.multiaxis import MultiAxis
from fiber_align.alignment.states import dbm, PEAKING, TRACKING, um
from fiber_align.alignment.visit import PointPeaking
from fiber_align.config import load_params
from fiber_align.plant import array_optics as ao

CONFIG_FILE, CONFIG_NODE = 'array.yaml', 'array_sequencer'
AXES3 = ('x', 'y_left', 'y_right')
#: The drivers of the three actuators, as :attr:`ArrayMachine.drivers` names them.
DRIVERS = tuple('%s/actuator_driver' % a for a in AXES3)


def load_geometry():
    """Return the array's geometry (``channels``, ``pitch_m``, ``roll_arm_m``) from config."""
    g = load_params(ao.CONFIG_FILE, ao.CONFIG_NODE)
    return {k: g[k] for k in ao.GEOMETRY_KEYS}


class ArrayMachine(MultiAxis, Machine, PointPeaking):
    """Find, peak and track the array in x, y and roll (see the module docstring)."""

    CREST = True
    SEARCH_PHASE = 'search'
    DITHERS = (('dither_x_frequency_hz', (0,)), ('dither_left_frequency_hz', (1,)),
               ('dither_right_frequency_hz', (2,)))
    AXIS_NAMES = AXES3
    method = 'joint'

    def __init__(self, params=None, period_s=None, path_rate_m_per_s=None, geometry=None,
                 **overrides):
        """
        Build from a parameter mapping (None: ``config/array.yaml``); every key required.

        :param period_s: period of the :meth:`update` calls (s), required.
        :param path_rate_m_per_s: the fastest the realtime loop follows a setpoint (m/s),
            or None (offline).
        :param geometry: ``channels``, ``pitch_m``, ``roll_arm_m`` (None: from config).
        """
        p = check_params(load_params(CONFIG_FILE, CONFIG_NODE), params, overrides, 'array')
        g = load_geometry() if geometry is None else geometry
        self.drivers = DriverState(DRIVERS)
        if not p['range_max_m'] > p['range_min_m']:
            raise ValueError('range_max_m must exceed range_min_m')
        if len({p[k] for k, _ in self.DITHERS}) < 3:
            raise ValueError('the three dithers need distinct frequencies')
        self.roll_arm_m = float(g['roll_arm_m'])
        u = ao.positions_along(g['channels'], g['pitch_m'])
        self.u_outer = np.array([u[0], u[-1]])
        #: the outer channels as a fault names them, and those whose reading is missing now
        self.outer_names, self._silent = ('1', 'N (%d)' % len(u)), []
        self.curvature_prior = 1.0 / p['coupling_radius_m'] ** 2
        self._history, self._pw2, self._center, self._path = [], None, None, None
        self._bright = (0.0, None)     # this peak's brightest reading: (W, actuators m)
        park = ao.actuators(p['nominal_x_m'], p['nominal_y_m'], 0.0, self.roll_arm_m)
        self._init_axes(p, park, np.full(3, float(p['range_min_m'])),
                        np.full(3, float(p['range_max_m'])), period_s, path_rate_m_per_s)
        self.line_pitch_m = s2.spiral_pitch(p['coupling_radius_m'], p['search_capture_db'],
                                            self.confirm_chord_m)

    # ---- the outer channels' coordinates ---------------------------------------------
    def to_channels(self, a):
        """Return ``(x, y_1, y_N)`` (m) of the actuators ``a`` = ``(x, y_l, y_r)`` (m)."""
        x, y, roll = ao.pose(a, self.roll_arm_m)
        return np.array([x, *(y + self.u_outer * math.sin(roll))])

    def to_actuators(self, c):
        """Return ``(x, y_l, y_r)`` (m) that put the outer channels at ``c`` (m)."""
        s = min(max((c[2] - c[1]) / (self.u_outer[1] - self.u_outer[0]), -0.5), 0.5)
        return np.array(ao.actuators(c[0], c[1] - self.u_outer[0] * s, math.asin(s),
                                     self.roll_arm_m))

    def _curvatures(self):
        """Return ``k`` of the channels' mean ``ln P`` per actuator (1/m^2, linearised)."""
        a = 0.5 - self.u_outer / self.roll_arm_m          # d y_i / d y_left
        b = 0.5 + self.u_outer / self.roll_arm_m          # d y_i / d y_right
        k = self.curvature_prior
        return [k, k * float(np.mean(a * a)), k * float(np.mean(b * b))]

    # ---- the control-period step ---------------------------------------------------
    def update(self, t_s, positions_m, powers_w, driver_active=None):
        """
        Advance one control period; return the three setpoints (m).

        :param positions_m: the measured ``(x, y_left, y_right)`` (m), or None.
        :param powers_w: the readings ``(P_1, P_N)`` of the outer channels (W), or None.
        :param driver_active: None (as the drivers published), a bool, or three bools.
        """
        pw2 = None
        ok = [v is not None and math.isfinite(v) for v in (powers_w or (None, None))]
        self._silent = [c for c, k in zip(self.outer_names, ok) if not k]
        if all(ok):
            pw2 = np.asarray(powers_w, dtype=float)
        self._pw2 = pw2                 # the search, the floor, HELD: the brighter channel
        return self._update(t_s, positions_m, None if pw2 is None else max(pw2.tolist()),
                            driver_active)

    def _power_text(self):
        """Name the meters without a reading: ``channel N (8)'s power meter`` (the readings)."""
        return ' and '.join("channel %s's power meter" % c for c in self._silent) or \
            'optical power'

    def _do_peaking(self, t, pos, pw):
        self._do_visit(t, pos, self._pw2)

    def _do_tracking(self, t, pos, pw):
        p = None if self._pw2 is None else self._pw2.tolist()
        gm = None if p is None else math.sqrt(max(p[0] * p[1], 0.0))
        super()._do_tracking(t, pos, gm)

    def _hold_center(self):
        if self.state == PEAKING and self._center is not None:
            return self.to_actuators(self._center)
        return np.array(self.aligned, dtype=float) if self.state in (PEAKING, TRACKING) \
            else None

    # ---- SEARCHING -----------------------------------------------------------------
    def search_path(self, start):
        """Return the first-light raster (:class:`~station_search.Polyline`) from ``start``."""
        p = self.p
        half = p['search_half_width_m']
        lines = max(1, int(math.ceil(2.0 * half / self.line_pitch_m)))
        xy = ss.raster_vertices((p['nominal_x_m'], p['nominal_y_m']), half, lines)
        v = [np.asarray(start, dtype=float)] + [np.array([x, y, y]) for x, y in xy]
        return ss.Polyline(np.clip(np.asarray(v), self.lo, self.hi))

    def _no_light_text(self):
        return ('no light found on either outer channel within %.1f um of (%.1f, %.1f) um '
                'at roll 0 (threshold %.1f dBm): broken fiber or chip, no source, or the '
                'chip out of the stroke' % (self.p['search_half_width_m'] * 1e6,
                                            self.p['nominal_x_m'] * 1e6,
                                            self.p['nominal_y_m'] * 1e6, dbm(self.threshold_w)))

    # ---- PEAKING: the joint pattern --------------------------------------------------
    def _start_pattern(self, center, radius):
        """Visit the pattern of ``radius`` (m) around the actuators ``center`` (m)."""
        self._phase = 'pattern'
        c = self.to_channels(np.clip(np.asarray(center, float), self.lo, self.hi))
        self._center, self._radius = c, float(radius)
        sign = 1.0 if self.iterations % 2 == 0 else -1.0
        pts = [c] + [c + sign * self._radius * e for e in np.eye(3)]
        self._visit([self.to_actuators(q) for q in pts], self._fit_joint)

    def _channel_fits(self, rows):
        """Fit each outer channel's paraboloid in its own plane; None for a dark one."""
        c = np.array([self.to_channels(r[:3]) for r in rows])
        fits = []
        for j in (0, 1):
            ok, w = self._weights(rows[:, 3 + j])
            fit = None
            if ok.sum() >= 3:
                fit = s2.fit_log_paraboloid_groups(c[ok][:, [0, 1 + j]], rows[ok, 3 + j],
                                                   ((0, 1),), w[ok], self.curvature_prior)
            fits.append(fit)
        return fits

    def _fit_joint(self, rows):
        p = self.p
        self.iterations += 1
        # the previous pattern too when it was near (its points on the other side)
        near = [r for c, r in self._history[-1:]
                if np.linalg.norm(c - self._center) <= 2.0 * p['pattern_radius_max_m']]
        self._history = (self._history + [(self._center, rows)])[-2:]
        fits = self._channel_fits(np.vstack(near + [rows]))
        c = self._center
        top = rows[:, 3:5].max(axis=1)
        i = int(np.argmax(top))
        if self.iterations == 1 or top[i] > self._bright[0]:
            lit_i = self._weights(top[i:i + 1])[0][0]
            self._bright = (top[i] if lit_i else 0.0, rows[i, :3].copy())
        if fits[0] is None and fits[1] is None:
            lit = self._weights(rows[:, 3:5].max(axis=1))[0]
            if not lit.any() and self.iterations == 1:
                return self._false_light()
            back = self._bright[0] > 0 and np.linalg.norm(
                self.to_actuators(c) - self._bright[1]) > p['pattern_radius_min_m']
            if not lit.any() and back:
                # a step from lit patterns went dark (a fit far down the tail, one channel
                # dark, can point the wrong way): back to this peak's brightest reading
                self._log('pattern %d dark: back to the brightest reading, at %s'
                          % (self.iterations, um(self._bright[1])))
                return self._iterate(self._bright[1], p['pattern_radius_min_m'])
            if not lit.any():
                return self._fault('light lost while peaking: no reading above %.1f dBm '
                                   'around %s' % (dbm(p['fit_min_snr'] * self.floor[1]),
                                                  um(self.to_actuators(c))))
            best = rows[int(np.argmax(rows[:, 3:5].max(axis=1))), :3]
            return self._iterate(best, self._radius)
        v = [None if f is None else f[0] for f in fits]
        both = v[0] is not None and v[1] is not None
        if both:
            vertex = np.array([0.5 * (v[0][0] + v[1][0]), v[0][1], v[1][1]])
        else:                           # one channel dark: move rigidly with the lit one
            j = 0 if v[0] is not None else 1
            vertex = c + (v[j][1] - c[1 + j])
            vertex[0] = v[j][0]
        self._fit = fits
        act = self.to_actuators(vertex)
        tol, edge = p['range_tolerance_m'], p['settle_tolerance_m']
        # out of reach only where the pattern already stands at the range's edge (as the
        # rig's and the station's fits, visit.py) and both channels are fitted: a fit of a
        # far tail's readings (or one channel's, the other dark) can put its vertex
        # anywhere, and the step towards it is bounded and clipped to the range
        at = self.to_actuators(c)
        at_edge = (np.abs(at - self.lo) < edge) | (np.abs(at - self.hi) < edge)
        if both and np.any(((act < self.lo - tol) | (act > self.hi + tol)) & at_edge):
            return self._fault('target out of reach: peak estimated at %s (x, y_left, '
                               'y_right), reachable %.1f..%.1f um'
                               % (um(act), self.lo[0] * 1e6, self.hi[0] * 1e6))
        step = vertex - c
        dist = float(np.linalg.norm(step))
        self._log('pattern %d at %s, radius %.2f um: vertex %s%s'
                  % (self.iterations, um(c), self._radius * 1e6, um(vertex),
                     '' if both else ' (one channel dark)'))
        if dist > p['max_step_m']:
            step *= p['max_step_m'] / dist
        if dist < p['converge_tolerance_m'] and both:
            self._vertex = vertex
            return self._verify_at(act)
        self._iterate(self.to_actuators(c + step), dist=dist)

    def _predicted_w(self, vertex):
        """Return the powers (W) the two channels' fits predict at ``vertex`` (channels)."""
        out = []
        for j, (v, k, lp0) in enumerate(self._fit):
            d = np.array([vertex[0] - v[0], vertex[1 + j] - v[1]])
            out.append(math.exp(lp0 - k[0] * float(d @ d)))
        return np.array(out)

    def _verify(self, rows):
        """Judge the reading at the vertex on both channels: TRACKING, or another pattern."""
        p = self.p
        meas = rows[0, 3:5]
        miss_db = float(np.max(10.0 * np.log10(self._predicted_w(self._vertex)
                                               / np.maximum(meas, 1e-300))))
        if miss_db > p['verify_tolerance_db'] and self.iterations < int(p['max_iterations']):
            self._log('reading %.3f dB below the fitted peak; another pattern' % miss_db)
            self._start_pattern(rows[0, :3], p['pattern_radius_min_m'])
            return
        self.aligned = self._visiting.goal.copy()
        self.aligned_power_w = float(math.sqrt(meas[0] * meas[1]))
        self._start_tracking(self._t)
