# SPDX-License-Identifier: Apache-2.0
"""
The coupled station's sequencer: input and output fiber aligned through a chip at once.

A pure, step-based state machine for four axes ``(x_in, y_in, x_out, y_out)`` (m). Once per
control period the loop calls ``seq.update(t_s, positions_m, power_w)`` with the four
measured displacements (m) and the output detector's reading (W) and gets the four
setpoints back. Commands and states are those of :class:`~fiber_align.alignment.machine.
Machine` (``align``, ``release``, ``switch``; IDLE, SEARCHING, PEAKING, TRACKING,
RELEASING, FAULT), and HELD while a driver holds its output
(:mod:`~fiber_align.alignment.station_hold`).

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
    displacements (:class:`~fiber_align.alignment.station_search.JointDemodulator`) gives
    both sides' gradients; each side's estimate moves at ``bandwidth * g / (2 k)`` with its
    own curvature ``k``: a loop of bandwidth ``tracking_bandwidth_rad_s`` on every axis.

Defaults: node ``station_sequencer`` of ``config/station.yaml``. SI units (s, m, W).
"""

import math

import numpy as np

from fiber_align.alignment import station_search as ss
from fiber_align.alignment.driver_state import DriverState
from fiber_align.alignment.machine import Machine
from fiber_align.alignment.multiaxis import MultiAxis
from fiber_align.alignment.peak2d import dbm
from fiber_align.alignment.sequencer2d import default_period_s, PATH_RATE_SHARE
from fiber_align.alignment.states import ACTIVE, IDLE, PEAKING, SEARCHING, TRACKING
from fiber_align.alignment.station_hold import axes_down, StationHold
from fiber_align.alignment.station_peak import AXES4, JointPeakMixin, um
from fiber_align.config import load_params

CONFIG_FILE = 'station.yaml'
CONFIG_NODE = 'station_sequencer'
NOMINAL_KEYS = ('nominal_in_x_m', 'nominal_in_y_m', 'nominal_out_x_m', 'nominal_out_y_m')


def load_station_params(**overrides):
    """Return the parameters of node ``station_sequencer``, ``overrides`` applied."""
    p = dict(load_params(CONFIG_FILE, CONFIG_NODE))
    p.update(overrides)
    return p


#: The drivers of the four axes, as :attr:`Station.drivers` names them (the station
#: graph's ``in/x`` ... ``out/y`` namespaces).
DRIVERS = tuple('%s/%s/actuator_driver' % (side, a) for side in ('in', 'out')
                for a in ('x', 'y'))


class Station(StationHold, MultiAxis, Machine, JointPeakMixin):
    """Find, peak and track both fibers of the station (see the module docstring)."""

    AXIS_NAMES = AXES4

    method = 'concurrent'

    def __init__(self, params=None, period_s=None, path_rate_m_per_s=None, **overrides):
        """
        Build from a parameter mapping (None: ``config/station.yaml``); every key required.

        :param period_s: period of the :meth:`update` calls (s); None: 1 / ``rate_hz``.
        :param path_rate_m_per_s: the fastest the realtime loop follows a setpoint (m/s);
            the search walks at most ``PATH_RATE_SHARE`` of it (as the 2-D sequencer).
            None or <= 0: no bound (offline, lockstep).
        """
        base = load_params(CONFIG_FILE, CONFIG_NODE)
        p = dict(base if params is None else params)
        p.update(overrides)
        missing, unknown = sorted(set(base) - set(p)), sorted(set(p) - set(base))
        if missing or unknown:
            raise ValueError('station parameters: missing %s, unknown %s'
                             % (missing or 'none', unknown or 'none'))
        #: what the four drivers published (the commands' refusals read it)
        self.drivers = DriverState(DRIVERS)
        if not p['range_max_m'] > p['range_min_m']:
            raise ValueError('range_max_m must exceed range_min_m')
        if p['dither_in_frequency_hz'] == p['dither_out_frequency_hz']:
            raise ValueError('the two dithers need distinct frequencies')
        self.p = p
        self.lo = np.full(4, float(p['range_min_m']))
        self.hi = np.full(4, float(p['range_max_m']))
        self.park = np.array([p[k] for k in NOMINAL_KEYS], dtype=float)
        self.period_s = default_period_s() if period_s is None else float(period_s)
        self.search_speed = float(p['search_speed_m_per_s'])
        if path_rate_m_per_s is not None and path_rate_m_per_s > 0:
            self.search_speed = min(self.search_speed, PATH_RATE_SHARE * path_rate_m_per_s)
        chord = (int(p['confirm_samples']) + 1) * self.search_speed * self.period_s
        self.grid_n, self.lines_m = ss.search_design(
            p['coupling_radius_m'], p['search_capture_db'], p['search_slow_share'], chord,
            p['search_half_width_m'])
        self.curvature_prior = 1.0 / p['coupling_radius_m'] ** 2
        self.state = IDLE
        self.fault_reason = ''
        self.events = []
        self.aligned = None
        self.aligned_power_w = None
        self.curvatures_per_m2 = None
        self.threshold_w = None
        self.floor = None
        self.first_light_t = None
        self.peak_samples = self.search_samples = self.iterations = 0
        self.sp = self.park.copy()
        self.dt = 0.0
        self._t = None
        self._last = {'p': None, 'y': None}
        self._follow_since = None
        self._prev_pos = None
        self._idle_buf = []
        self._history = []
        self._down = False
        self._phase = ''
        self._enter(IDLE)

    # ---- commands (Machine) --------------------------------------------------------
    def _start_search(self):
        self._phase = 'floor'
        self._floor_buf = list(self._idle_buf)

    def _park_text(self):
        return um(self.park)

    def _aligned_point(self):
        return self.aligned

    def _start_repeak(self):
        self._history = []
        self._start_joint(self.aligned, self.p['repeak_pattern_radius_m'])
        return 'switching on to %s' % um(self.aligned)

    def search_path(self, start):
        """Return the first-light walk (:class:`~station_search.Polyline`) from ``start``."""
        p = self.p
        v = ss.search_vertices(start, self.park[:2], self.park[2:], p['search_half_width_m'],
                               self.grid_n, self.lines_m, self.lo, self.hi)
        return ss.Polyline(v)

    @property
    def setpoint(self):
        """Return the four setpoints (m)."""
        return tuple(float(v) for v in self.sp)

    # ---- the control-period step ---------------------------------------------------
    def update(self, t_s, positions_m, power_w, driver_active=None):
        """
        Advance one control period; return the four setpoints (m).

        :param t_s: time of the readings (s).
        :param positions_m: the measured ``(x_in, y_in, x_out, y_out)`` (m), or None.
        :param power_w: output detector reading (W), or None.
        :param driver_active: None (not known), a bool for all four drivers, or four
            bools (``x_in, y_in, x_out, y_out``): False when that driver is not driving
            (HELD: :mod:`~fiber_align.alignment.station_hold`).
        """
        t = float(t_s)
        self.dt = 0.0 if self._t is None else max(0.0, t - self._t)
        self._t = t
        pos = None
        if positions_m is not None and all(v is not None and math.isfinite(v)
                                           for v in positions_m):
            pos = np.asarray(positions_m, dtype=float)
            self._last['y'] = t
        pw = None if power_w is None or not math.isfinite(power_w) else float(power_w)
        if pw is not None:
            self._last['p'] = t
        if driver_active is None and not self.drivers.pending:
            # what the drivers published (the graph's nodes); pending: a re-activated
            # driver whose drive_held false is on its way is no reason to hold
            driver_active = self.drivers.each
        down = axes_down(driver_active)
        self._down = bool(down)
        if self.state in ACTIVE and down:
            self._hold(t, down)
        if self.state in ACTIVE and self._unhealthy(t, pos):
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
        self.sp = np.clip(self.sp, self.lo, self.hi)
        return self.setpoint

    def status(self):
        """Return a dict of the state (SI)."""
        al = self.aligned
        return dict(state=self.state, phase=self._phase, fault_reason=self.fault_reason,
                    setpoints_m=list(self.setpoint),
                    aligned_m=None if al is None else [float(v) for v in al],
                    threshold_w=self.threshold_w, hold_reason=self.hold_reason,
                    peak_samples=self.peak_samples,
                    search_samples=self.search_samples, iterations=self.iterations)

    def _driver_down(self, reason):
        """Hold at once: a driver stopped driving (``Machine``'s driver calls)."""
        self._hold(self._t, axes_down(self.drivers.each) or list(AXES4))
        self.hold_reason += ' (%s)' % reason

    # ---- health, IDLE, RELEASING ---------------------------------------------------
    def _unhealthy(self, t, pos):
        """Return True (and fault) when a reading is missing or an axis does not follow."""
        return self._silent_or_stuck(t, pos)

    # ---- SEARCHING -----------------------------------------------------------------
    def _do_searching(self, t, pos, pw):
        p = self.p
        if self._elapsed(t) > p['search_timeout_s']:
            self._fault('no light found: search timed out after %.0f ms at %s (threshold '
                        '%.1f dBm)' % (self._elapsed(t) * 1e3, um(pos), dbm(self.threshold_w)))
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
                self._log('light present at the start (%.1f dBm)' % dbm(mean))
                self.first_light_t = t
                self._start_peaking(pos)
                return
            self.threshold_w = max(mean + p['threshold_sigma'] * std, p['min_threshold_w'])
            self._path = self.search_path(pos)
            self._phase = 'search'
            self._confirm = 0
            self._best = (0.0, pos)
        if pw is not None and pw > self._best[0]:
            self._best = (pw, pos)
        if self._phase == 'crest':
            # past first light the pass goes on to its brightest reading (it crosses the
            # lit region): a far better start for the fit than the threshold's edge
            self._crest += 1
            if pw is None or pw < self._best[0] or self._crest >= int(p['crest_max_samples']):
                self._log('first light %.1f dBm at %s' % (dbm(self._best[0]),
                                                          um(self._best[1])))
                self._start_peaking(self._best[1])
                return
        elif pw is not None and pw > self.threshold_w:
            self._confirm += 1
            if self._confirm >= int(p['confirm_samples']):
                self.first_light_t = t
                self._phase, self._crest = 'crest', 0
        else:
            self._confirm = 0
        if self._path.done:
            if np.all(np.abs(pos - self.sp) < 4 * p['settle_tolerance_m']):
                c, h = self.park * 1e6, p['search_half_width_m'] * 1e6
                self._fault('no light found with the input fiber anywhere within %.1f um of '
                            '(%.1f, %.1f) um and the output fiber within %.1f um of (%.1f, '
                            '%.1f) um on each axis (threshold %.1f dBm): broken fiber or '
                            'chip, no source, or a facet out of the search square'
                            % (h, c[0], c[1], h, c[2], c[3], dbm(self.threshold_w)))
            return
        self.sp = self._path.advance(self.search_speed * self.dt)

    def _false_light(self):
        """Nothing lit around the first-light point: a noise spike; walk on (same path)."""
        self._log('no light around the first-light point: noise, searching on')
        self.state = SEARCHING
        self.events.append((self._t, SEARCHING, 'resumed'))
        self._phase = 'search'
        self._confirm = 0
        self._best = (0.0, self.sp.copy())

    # ---- PEAKING -------------------------------------------------------------------
    def _start_peaking(self, center):
        self._enter(PEAKING)
        self._history = []
        self._start_joint(center, self.p['pattern_radius_first_m'])

    def _do_peaking(self, t, pos, pw):
        self._do_visit4(t, pos, pw)

    # ---- TRACKING ------------------------------------------------------------------
    def _start_tracking(self, t):
        self._enter(TRACKING)
        self._xhat = np.asarray(self.aligned, dtype=float).copy()
        self._track_t0 = t
        self._loss_since = None
        self._demod = ss.JointDemodulator(4, self.p['gradient_time_s'], self.p['power_lag_s'])

    def _lost_power(self, t, pw):
        """Return True (and fault after the timeout) while the power is far below aligned."""
        p = self.p
        if pw is not None and pw < self.aligned_power_w * 10 ** (-p['track_loss_db'] / 10.0):
            if self._loss_since is None:
                self._loss_since = t
            elif t - self._loss_since > p['track_loss_timeout_s']:
                self._fault('power lost while tracking: %.1f dBm, more than %.0f dB below the '
                            'aligned %.1f dBm (broken fiber or chip, source off)'
                            % (dbm(pw), p['track_loss_db'], dbm(self.aligned_power_w)))
            return True
        self._loss_since = None
        return False

    def _do_tracking(self, t, pos, pw):
        p = self.p
        if self._lost_power(t, pw):
            return
        a = p['dither_radius_m']
        if pw is not None and pw > 0:
            self._demod.update(self.dt, pos, math.log(pw))
            g = self._demod.gradient(0.1 * a * a)
            if g is not None and t - self._track_t0 > p['gradient_time_s']:
                k = self.curvatures_per_m2 or (self.curvature_prior, self.curvature_prior)
                kk = np.array([k[0], k[0], k[1], k[1]])
                step = p['tracking_bandwidth_rad_s'] * self.dt / (2.0 * kk) * g
                lim = p['tracking_bandwidth_rad_s'] * self.dt * 5 * a
                n = float(np.linalg.norm(step))
                self._xhat += step * (min(1.0, lim / n) if n > 0 else 1.0)
        self._xhat = np.clip(self._xhat, self.lo, self.hi)
        self.aligned = self._xhat.copy()
        dt = t - self._track_t0
        ph_in = 2.0 * math.pi * p['dither_in_frequency_hz'] * dt
        ph_out = 2.0 * math.pi * p['dither_out_frequency_hz'] * dt
        self.sp = self._xhat + a * np.array([math.cos(ph_in), math.sin(ph_in),
                                             math.cos(ph_out), math.sin(ph_out)])
