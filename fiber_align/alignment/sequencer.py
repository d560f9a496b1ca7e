# SPDX-License-Identifier: Apache-2.0
"""
Alignment sequencer: a pure, step-based state machine that finds, peaks and tracks light.

Once per control period the loop calls ``seq.update(t_s, displacement_m, power_w)`` and
gets the displacement setpoint (m) back. Commands ``align()``, ``release()`` and
``switch(on)`` return ``(ok, message)``. ``state`` and ``fault_reason`` tell where it is.

States::

    IDLE -> SEARCHING -> PEAKING -> TRACKING      (align)
    any  -> RELEASING -> IDLE                     (release, switch(False))
    IDLE -> PEAKING (re-peak) -> TRACKING         (switch(True): to the last aligned spot)
    SEARCHING, PEAKING, TRACKING -> HELD          (the driver holds its output)
    HELD -> PEAKING (re-peak) or SEARCHING        (the driver drives again)
    any active state -> FAULT (reason)

SEARCHING
    Measures the detector floor at rest (the IDLE samples count), sets the first-light
    threshold ``threshold_sigma`` standard deviations above its mean, then ramps the
    setpoint across the reachable range until the power stays above the threshold for
    ``confirm_samples`` samples. A floor that is already bright (above ``floor_max_w``)
    means light is present at the start: it goes straight to PEAKING.
PEAKING
    Continues the sweep through the peak and fits a parabola to ``ln P`` against the
    measured displacement (the Gaussian mode overlap makes ``ln P`` exactly quadratic in
    the offset, so a three-parameter least-squares fit on one sweep locates the peak; see
    docs/alignment.md for the sample counts of the alternatives). It moves to the vertex,
    waits for the loop to settle, and checks the power against the fitted peak; a miss
    triggers a short local re-sweep. ``switch(True)`` uses the same local re-sweep.
HELD, TRACKING
    Every machine's: :mod:`fiber_align.alignment.hold` (back at the held setpoint, a local
    re-peak, or the search again without light) and :mod:`fiber_align.alignment.tracking`
    (dither extremum seeking). A trip in the first sweep through the peak goes on with
    that sweep (the readings before the trip stay valid).

All quantities are SI (s, m, W); dB only for ratios. Defaults: ``config/sequencer.yaml``.
"""

import numpy as np

from fiber_align.alignment.driver_state import DriverState
from fiber_align.alignment.machine import check_params, Machine
from fiber_align.alignment.peaking import Peaking
from fiber_align.alignment.states import (ACTIVE, dbm, FAULT, HELD, IDLE,  # noqa: F401
                                          PEAKING, RELEASING, SEARCHING, TRACKING)
from fiber_align.config import load_params

CONFIG_FILE = 'sequencer.yaml'
CONFIG_NODE = 'alignment_sequencer'


class Sequencer(Machine, Peaking):
    """Find, peak, track and switch the light on one axis (see the module docstring)."""

    AXIS_NAMES = ('the actuator',)
    DITHERS = (('dither_frequency_hz', (0,)),)
    DITHER_AMPLITUDE = 'dither_amplitude_m'
    TRACK_LAG = False           # each reading with the same period's displacement

    def __init__(self, params=None, **overrides):
        """
        Build a sequencer from a parameter mapping (``None``: config/sequencer.yaml).

        :param params: every key of the file's ``alignment_sequencer`` node (SI units; the
            file is the one source of defaults).
        :param overrides: keys that win over ``params``.
        :raises ValueError: a missing or unknown key.
        """
        p = check_params(load_params(CONFIG_FILE, CONFIG_NODE), params, overrides,
                         'sequencer')
        if not p['range_max_m'] > p['range_min_m']:
            raise ValueError('range_max_m must exceed range_min_m')
        self.aligned_position_m = None
        self.curvature_per_m2 = None
        self._setpoint = p['park_position_m']
        self.park = np.array([p['park_position_m']])
        self.lo, self.hi = np.array([p['range_min_m']]), np.array([p['range_max_m']])
        self.drivers = DriverState()
        self._init_machine(p)

    # ---- commands (Machine: align, release, switch) ----------------------------------
    def _start_search(self):
        self._phase = 'start'

    @property
    def aligned(self):
        """Return the last aligned position as the one entry of an array (m), or None."""
        return None if self.aligned_position_m is None else np.array([self.aligned_position_m])

    @aligned.setter
    def aligned(self, value):
        self.aligned_position_m = float(np.asarray(value, dtype=float).reshape(-1)[0])

    @property
    def sp(self):
        """Return the setpoint as the one entry of an array (m; the machines' shape)."""
        return np.array([self._setpoint])

    @sp.setter
    def sp(self, value):
        self._setpoint = float(np.asarray(value, dtype=float).reshape(-1)[0])

    def _hold_center(self):
        """Return where a re-peak after the HELD starts (m); None: held while searching."""
        self._sweep_on = (self.state == PEAKING and self._phase == 'sweep'
                          and self._first_sweep)
        if self.state == TRACKING:
            return float(self._tracker.xhat[0])
        if self.state != PEAKING:
            return None
        if self._phase in ('goto', 'goto_peak', 'verify'):
            return self._goal
        return getattr(self, '_local_center', self._setpoint)

    def _repeak_after_hold(self, t, center):
        """Go on with the first sweep (the readings before the trip), or re-peak locally."""
        if self._sweep_on:
            self.state, self._state_t, self._phase = PEAKING, t, 'sweep'
            self._follow_since = None
            self.events.append((t, PEAKING, 'driver back: the sweep goes on'))
            return
        self._enter(PEAKING)
        self._refits, self._goto_phase = 0, None
        self._start_local(center)
        self._log('driver back: local re-peak around %.2f um' % (center * 1e6))

    def _start_repeak(self):
        self._phase = 'goto'
        self._goal = self.aligned_position_m
        self._switch_from = self._setpoint
        self._refits = 0
        return 'switching on to %.2f um' % (self.aligned_position_m * 1e6)

    @property
    def setpoint_m(self):
        """Return the last setpoint (m)."""
        return self._setpoint

    # ---- the control-period step ----------------------------------------------------
    def update(self, t_s, displacement_m, power_w, driver_active=None):
        """
        Advance one control period; return the displacement setpoint (m).

        :param t_s: time of the samples (s).
        :param displacement_m: measured displacement (m), or ``None`` if none arrived.
        :param power_w: optical power reading (W), or ``None`` if none arrived.
        :param driver_active: ``False`` while the driver holds its output (HELD: the
            setpoint is held until it drives again); ``True`` when it drives; ``None``:
            as :attr:`drivers` says (what the driver published, ``driver_held`` ...).
        """
        self._update(t_s, [displacement_m], power_w, driver_active)
        return self._setpoint

    def _driver_input(self):
        return self.drivers.active          # a pending drive_held true holds too

    def _handler_pos(self, pos):
        return float(pos[0])                # the 1-D steps take the displacement (m)

    # ---- internals ------------------------------------------------------------------
    # SEARCHING ------------------------------------------------------------------------
    def _do_searching(self, t, y, pw):
        p = self.p
        if self._elapsed(t) > p['search_timeout_s']:
            self._fault('no light found: search timed out after %.0f ms at %.1f um '
                        '(threshold %.1f dBm)' % (self._elapsed(t) * 1e3, y * 1e6,
                                                  dbm(self.threshold_w)))
            return
        if self._phase == 'start':
            self._setpoint = p['range_min_m']
            self._floor_buf = list(self._idle_buf)
            # the search starts at the start of travel, its floor is measured there: from
            # anywhere else (align while TRACKING, HELD, after a re-plug) it goes there first
            far = abs(y - p['range_min_m']) >= p['release_tolerance_m']
            self._phase = 'to_start' if far else 'floor'
        if self._phase == 'to_start':
            if not (self._rest and abs(y - p['range_min_m']) < p['release_tolerance_m']):
                return
            self._phase = 'floor'
        if self._phase == 'floor':
            bright = self._measure_floor(self._rest, pw)
            if bright is None:
                return
            if bright:
                self._start_peaking(t, y, pw)
                return
            self._phase = 'scan'
            self._confirm = 0
        if self._phase == 'scan':
            if pw is not None and pw > self.threshold_w:
                self._confirm += 1
                if self._confirm >= int(p['confirm_samples']):
                    self.first_light_t = t
                    self._start_peaking(t, y, pw)
                    return
            else:
                self._confirm = 0
            self._setpoint = min(self._setpoint + p['search_speed_m_per_s'] * self.dt,
                                 p['range_max_m'])
            if self._setpoint >= p['range_max_m'] and \
                    abs(y - p['range_max_m']) < p['release_tolerance_m']:
                self._fault('no light found anywhere in the reachable range %.1f..%.1f um '
                            '(threshold %.1f dBm): broken fiber, no source, or the slot is '
                            'outside the reachable range'
                            % (p['range_min_m'] * 1e6, p['range_max_m'] * 1e6,
                               dbm(self.threshold_w)))

    def status(self):
        """Return a dict describing the state (for topics, diagnostics and reports)."""
        return dict(state=self.state, phase=self._phase, fault_reason=self.fault_reason,
                    setpoint_m=self._setpoint, aligned_position_m=self.aligned_position_m,
                    threshold_w=self.threshold_w, peak_samples=self.peak_samples,
                    hold_reason=self.hold_reason)
