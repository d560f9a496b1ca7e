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
HELD
    A driver holds its output (a watchdog trip, ``~/enable`` false, inactive): the
    setpoints are held; once every driver drives again and both axes are back within
    ``follow_error_m`` of them, at rest, a search starts again (held while SEARCHING, or
    before any aligned point) or a re-peak around the last aligned point (PEAKING,
    TRACKING). FAULT when a driver stays down, or an axis does not return, for longer
    than ``driver_down_timeout_s``.
TRACKING
    Circular dither of radius ``dither_radius_m`` at ``dither_frequency_hz``; the demodulated
    gradient of ``ln P`` moves the estimate at ``bandwidth * g / (2 k)`` (``k`` the fitted
    curvature), an integral action whose loop bandwidth is ``tracking_bandwidth_rad_s``.

All quantities are SI (s, m, W); dB only for ratios. Defaults: ``config/sequencer2d.yaml``.
"""

import math

import numpy as np

from fiber_align.alignment import search2d as s2
from fiber_align.alignment.driver_state import DriverState
from fiber_align.alignment.machine import Machine
from fiber_align.alignment.multiaxis import MultiAxis
from fiber_align.alignment.peak2d import AXES, dbm as _dbm, PeakFitMixin
from fiber_align.alignment.states import (ACTIVE, FAULT, HELD, IDLE,  # noqa: F401
                                          PEAKING, RELEASING, SEARCHING, STATES,
                                          TRACKING)
from fiber_align.config import load_params

CONFIG_FILE = 'sequencer2d.yaml'
CONFIG_NODE = 'alignment_sequencer_2d'
#: Where the graph's control rate is set (``rate_hz``, Hz): the period is 1 / rate_hz.
RATE_FILE, RATE_NODE = 'plant.yaml', 'simulated_actuator'
#: The drivers of the two axes, as :attr:`Sequencer2D.drivers` names them.
DRIVERS = tuple('%s/actuator_driver' % a for a in AXES)


def load_sequencer2d_params(path=CONFIG_FILE, node=CONFIG_NODE, **overrides):
    """Return the parameters of ``node`` in a params file, ``overrides`` applied."""
    p = dict(load_params(path, node))
    p.update(overrides)
    return p


def default_period_s():
    """Return the graph's control period (s): 1 / ``rate_hz`` of the shipped config."""
    return 1.0 / float(load_params(RATE_FILE, RATE_NODE)['rate_hz'])


#: Share of the realtime path's rate the search walks at, at most: the rest is room for
#: the acceleration limit at the spiral's turns.
PATH_RATE_SHARE = 0.9


class Sequencer2D(MultiAxis, Machine, PeakFitMixin):
    """Find, peak, track and switch the light in x and y (see the module docstring)."""

    AXIS_NAMES = AXES

    def __init__(self, params=None, period_s=None, path_rate_m_per_s=None, **overrides):
        """
        Build from a parameter mapping (``None``: ``config/sequencer2d.yaml``).

        :param period_s: period of the :meth:`update` calls (s); ``None``: 1 / the
            graph's ``rate_hz``.
        :param path_rate_m_per_s: the fastest the realtime loop follows a setpoint (m/s,
            the graph's ``realtime_setpoint_rate_m_per_s``); the search walks at most
            :data:`PATH_RATE_SHARE` of it, so the actuators keep up with the spiral (a
            walk faster than its path lags further each period until the follow check
            faults). ``None`` or <= 0: no bound (offline, lockstep).

        Every key of the file's ``alignment_sequencer_2d`` node is required (the file is
        the one source of defaults); ``overrides`` replace keys.
        """
        base = load_params(CONFIG_FILE, CONFIG_NODE)
        p = dict(base if params is None else params)
        p.update(overrides)
        missing = sorted(set(base) - set(p))
        unknown = sorted(set(p) - set(base))
        if missing or unknown:
            raise ValueError('sequencer2d parameters: missing %s, unknown %s'
                             % (missing or 'none', unknown or 'none'))
        for a in AXES:
            if not p['range_%s_max_m' % a] > p['range_%s_min_m' % a]:
                raise ValueError('range_%s_max_m must exceed range_%s_min_m' % (a, a))
        self.p = p
        self.lo = np.array([p['range_x_min_m'], p['range_y_min_m']], dtype=float)
        self.hi = np.array([p['range_x_max_m'], p['range_y_max_m']], dtype=float)
        self.park = np.array([p['park_x_m'], p['park_y_m']], dtype=float)
        self.period_s = default_period_s() if period_s is None else float(period_s)
        self.search_speed = float(p['search_speed_m_per_s'])
        if path_rate_m_per_s is not None and path_rate_m_per_s > 0:
            self.search_speed = min(self.search_speed, PATH_RATE_SHARE * path_rate_m_per_s)
        chord = (int(p['confirm_samples']) + 1) * self.search_speed * self.period_s
        self.capture_radius_m = s2.capture_radius(p['mode_radius_m'], p['spiral_capture_db'])
        self.pitch_m = s2.spiral_pitch(p['mode_radius_m'], p['spiral_capture_db'], chord)
        self.curvature_prior = 1.0 / p['mode_radius_m'] ** 2
        self.state = IDLE
        self.fault_reason = ''
        self.events = []
        self.aligned = None            # (x, y) of the last aligned point (m)
        self.aligned_power_w = None
        self.curvature_per_m2 = None
        self.threshold_w = None
        self.floor = None              # (mean, sigma) of the dark readings (W)
        self.peak_samples = 0
        self.search_samples = 0
        self.iterations = 0
        self.sp = self.park.copy()
        self.dt = 0.0
        self._t = None
        self._last = {'p': None, 'y': None}
        self._follow_since = None
        self._prev_pos = None
        self._idle_buf = []
        self._phase = ''
        self.hold_reason = ''
        self._held_from = None
        self._driver_active = None
        self.drivers = DriverState(DRIVERS)
        self._enter(IDLE)

    # ---- commands (Machine: align, release, switch) ----------------------------------
    def _start_search(self):
        self._phase = 'floor'
        self._floor_buf = list(self._idle_buf)

    def _park_text(self):
        return '(%.1f, %.1f) um' % tuple(self.park * 1e6)

    def _aligned_point(self):
        return self.aligned

    def _driver_down(self, reason):
        self._hold(reason)

    def _hold(self, why):
        """Enter HELD from an active state: keep the setpoints, say why."""
        self._held_from = self.state
        self._enter(HELD)
        self._phase = 'down'
        self.hold_reason = ('driver down during %s at (%.2f, %.2f) um (%s): setpoints held, '
                            'waiting for the re-arm, FAULT after %.1f s'
                            % (self._held_from, self.sp[0] * 1e6, self.sp[1] * 1e6, why,
                               self.p['driver_down_timeout_s']))
        self._log(self.hold_reason)

    def _do_held(self, t, pos, pw):
        p = self.p
        if self._driver_active is False:
            if self._phase != 'down':               # down again while returning
                self._phase, self._state_t = 'down', t
            if self._elapsed(t) > p['driver_down_timeout_s']:
                self._fault('driver inactive: a driver held its output for more than %.1f s '
                            '(during %s) without a re-arm (~/enable true or a lifecycle '
                            'cycle): %s' % (p['driver_down_timeout_s'], self._held_from,
                                            self.drivers.reason or 'not driving'))
            return
        if self._phase == 'down':
            self._log('driver back after %.0f ms' % (self._elapsed(t) * 1e3))
            self._phase, self._state_t = 'return', t
        if not (self._rest and np.all(np.abs(pos - self.sp) < p['follow_error_m'])):
            if self._elapsed(t) > p['driver_down_timeout_s']:
                self._fault('driver inactive or actuator stuck: (%.1f, %.1f) um did not '
                            'return to the held setpoints (%.1f, %.1f) um within %.1f s'
                            % (pos[0] * 1e6, pos[1] * 1e6, self.sp[0] * 1e6,
                               self.sp[1] * 1e6, p['driver_down_timeout_s']))
            return
        self._resumed = True
        if self._held_from == SEARCHING or self.aligned is None:
            self._enter(SEARCHING)
            self._start_search()
        else:
            self._enter(PEAKING)
            self._log(self._start_repeak())

    def _start_repeak(self):
        self._start_pattern(self.aligned, self.p['repeak_pattern_radius_m'])
        return 'switching on to (%.2f, %.2f) um' % tuple(np.asarray(self.aligned) * 1e6)

    def spiral(self, start):
        """
        Return the first-light walk from ``start`` (m): the square's centre, then outwards.

        It ends half a pitch beyond the half-diagonal, so that in every direction an arm
        passes within half a pitch of the corners (the setpoints are clipped to the square,
        so the outer turn runs along its edges).
        """
        center = 0.5 * (self.lo + self.hi)
        r_max = 0.5 * float(np.hypot(*(self.hi - self.lo))) + 0.5 * self.pitch_m
        return s2.SpiralPath(start, center, self.pitch_m, r_max)

    @property
    def setpoint(self):
        """Return the last setpoints ``(x, y)`` (m)."""
        return float(self.sp[0]), float(self.sp[1])

    # ---- the control-period step ----------------------------------------------------
    def update(self, t_s, x_m, y_m, power_w, driver_active=None):
        """
        Advance one control period; return the setpoints ``(x_m, y_m)`` (m).

        :param t_s: time of the readings (s).
        :param x_m: measured x displacement (m), or ``None`` if none arrived.
        :param y_m: measured y displacement (m), or ``None`` if none arrived.
        :param power_w: optical power reading (W), or ``None`` if none arrived.
        :param driver_active: ``False`` when either axis' driver is not driving; ``None``:
            as :attr:`drivers` says (what the drivers published).
        """
        t = float(t_s)
        self.dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        pos = None
        if x_m is not None and y_m is not None and math.isfinite(x_m) and math.isfinite(y_m):
            pos = np.array([float(x_m), float(y_m)])
            self._last['y'] = t
        pw = None if power_w is None or not math.isfinite(power_w) else float(power_w)
        if pw is not None:
            self._last['p'] = t
        if driver_active is None and not self.drivers.pending:
            # pending: a re-activated driver whose drive_held false is still on its way
            # is no fault (a driver that stays held is caught by the follow check)
            driver_active = self.drivers.active
        self._driver_active = driver_active
        if self.state in ACTIVE and self._unhealthy(t, pos, pw, driver_active):
            return self.setpoint
        if pos is None:
            pos = self._prev_pos if self._prev_pos is not None else self.sp.copy()
        self._rest = self._prev_pos is not None and np.all(
            np.abs(pos - self._prev_pos) < self.p['settle_tolerance_m'])
        self._prev_pos = pos
        getattr(self, '_do_' + self.state.lower())(t, pos, pw)
        if self.state == PEAKING:
            self.peak_samples += 1
        elif self.state == SEARCHING:
            self.search_samples += 1
        self.sp = np.minimum(np.maximum(self.sp, self.lo), self.hi)
        return self.setpoint

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

    # ---- internals ------------------------------------------------------------------
    def _unhealthy(self, t, pos, pw, driver_active):
        """Return True (and fault) when a driver is down, a reading missing, an axis stuck."""
        if driver_active is False:
            self._hold(self.drivers.reason or 'a driver reports it is not driving its axis')
            return True
        return self._silent_or_stuck(t, pos)

    # SEARCHING ------------------------------------------------------------------------
    def _do_searching(self, t, pos, pw):
        p = self.p
        if self._elapsed(t) > p['search_timeout_s']:
            self._fault('no light found: search timed out after %.0f ms at (%.1f, %.1f) um '
                        '(threshold %.1f dBm)' % (self._elapsed(t) * 1e3, pos[0] * 1e6,
                                                  pos[1] * 1e6, _dbm(self.threshold_w)))
            return
        if self._phase == 'floor':
            if self._rest and pw is not None:
                self._floor_buf.append(pw)
            n = int(p['floor_samples'])
            if len(self._floor_buf) < n:
                return
            f = np.asarray(self._floor_buf[-n:])
            mean, std = float(f.mean()), float(f.std(ddof=1))
            self.floor = (mean, std)
            if np.ptp(f) <= 1e-9 * abs(mean):
                self._fault('sensor silent: optical power reading is stuck at %.3g W' % mean)
                return
            if mean > p['floor_max_w']:
                self.threshold_w = p['floor_max_w']
                self.floor = (0.0, p['floor_max_w'] / max(p['threshold_sigma'], 1.0))
                self._log('light present at the start (%.1f dBm)' % _dbm(mean))
                self._start_peaking(pos)
                return
            self.threshold_w = max(mean + p['threshold_sigma'] * std, p['min_threshold_w'])
            self._spiral = self.spiral(pos)
            self._phase = 'spiral'
            self._confirm = 0
            self._best = (0.0, pos)
        if pw is not None and pw > self._best[0]:
            self._best = (pw, pos)
        if pw is not None and pw > self.threshold_w:
            self._confirm += 1
            if self._confirm >= int(p['confirm_samples']):
                self.first_light_t = t
                self._start_peaking(self._best[1])
                return
        else:
            self._confirm = 0
        if self._spiral.done:
            if np.all(np.abs(pos - self.sp) < 4 * p['settle_tolerance_m']):
                self._fault('no light found anywhere in the reachable square x %.1f..%.1f um, '
                            'y %.1f..%.1f um (threshold %.1f dBm): broken fiber, no source, '
                            'or the target is out of reach'
                            % (self.lo[0] * 1e6, self.hi[0] * 1e6, self.lo[1] * 1e6,
                               self.hi[1] * 1e6, _dbm(self.threshold_w)))
            return
        self.sp = np.array(self._spiral.advance(self.search_speed * self.dt))

    # PEAKING: settled points, paraboloid fit --------------------------------------------
    def _start_peaking(self, center):
        self._enter(PEAKING)
        self._start_pattern(center, self.p['pattern_radius_first_m'])

    def _do_peaking(self, t, pos, pw):
        self._do_visit(t, pos, pw)

    # TRACKING: circular dither --------------------------------------------------------
    def _start_tracking(self, t):
        self._enter(TRACKING)
        self._xhat = np.asarray(self.aligned, dtype=float).copy()
        self._track_t0 = t
        self._loss_since = None
        self._demod = s2.CircleDemodulator(self.p['gradient_time_s'], self.p['power_lag_s'])

    def _lost_power(self, t, pw):
        """Return True (and fault) when the power stayed far below the aligned power."""
        p = self.p
        if pw is not None and pw < self.aligned_power_w * 10 ** (-p['track_loss_db'] / 10.0):
            if self._loss_since is None:
                self._loss_since = t
            elif t - self._loss_since > p['track_loss_timeout_s']:
                self._fault('power lost while tracking: %.1f dBm, more than %.0f dB below the '
                            'aligned %.1f dBm (broken fiber, source off or target moved away)'
                            % (_dbm(pw), p['track_loss_db'], _dbm(self.aligned_power_w)))
                return True
            return True
        self._loss_since = None
        return False

    def _do_tracking(self, t, pos, pw):
        p = self.p
        if self._lost_power(t, pw):
            return
        a = p['dither_radius_m']
        if pw is not None and pw > 0:
            self._demod.update(self.dt, pos[0], pos[1], math.log(pw))
            g = self._demod.gradient(0.1 * a * a)
            if g is not None and t - self._track_t0 > p['gradient_time_s']:
                gain = p['tracking_bandwidth_rad_s'] * self.dt / (2.0 * self.curvature_per_m2)
                step = gain * np.asarray(g)
                lim = p['tracking_bandwidth_rad_s'] * self.dt * 5 * a
                n = float(np.hypot(*step))
                self._xhat += step * (min(1.0, lim / n) if n > 0 else 1.0)
        self._xhat = np.minimum(np.maximum(self._xhat, self.lo), self.hi)
        self.aligned = self._xhat.copy()
        ph = 2.0 * math.pi * p['dither_frequency_hz'] * (t - self._track_t0)
        self.sp = self._xhat + a * np.array([math.cos(ph), math.sin(ph)])
