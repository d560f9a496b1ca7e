# SPDX-License-Identifier: Apache-2.0
"""
What every alignment state machine shares, for any number of axes.

:class:`Machine` is the base of the 1-D :class:`~fiber_align.alignment.sequencer.Sequencer`,
the 2-D :class:`~fiber_align.alignment.sequencer2d.Sequencer2D` and the station's
:class:`~fiber_align.alignment.station.Station`: the commands ``align()``, ``release()``,
``switch(on)`` (each returns ``(ok, message)``), the period's step (:meth:`Machine._update`:
readings, HELD, health, the state's step), IDLE, RELEASING, the floor, state entry, faults
and the event log. HELD is the one :class:`~fiber_align.alignment.hold.Hold` it owns
(``hold``), TRACKING the one :class:`~fiber_align.alignment.tracking.Tracker`. What differs
per machine, a subclass provides: ``sp`` (the setpoints, an array, m), ``aligned`` (the last
aligned point, an array, m, or None), ``park``, ``lo``, ``hi`` (m), ``AXIS_NAMES``,
``DITHERS`` (TRACKING's), ``_start_search()``, ``_start_repeak()`` (after ``switch(True)``;
returns the message), ``_hold_center()`` (what a re-peak after a HELD starts from;
``None``: search again), ``_repeak_after_hold(t, center)`` and ``_driver_input()`` (what
the drivers published, for ``update``).

What the drivers publish reaches the machine through ``driver_held``, ``driver_lifecycle``,
``driver_diagnostics`` and ``driver_gone`` (the rules:
:class:`~fiber_align.alignment.driver_state.DriverState`, in ``drivers``): a driver that
stops driving in an active state holds it at once, not at the next sample; ``align`` and
``switch(True)`` are refused while a driver is down. SI units: s, m, W.
"""

import math

import numpy as np

from fiber_align.alignment.hold import Hold
from fiber_align.alignment.states import (ACTIVE, dbm, FAULT, HELD, IDLE, PEAKING,
                                          RELEASING, SEARCHING, TRACKING, um)
from fiber_align.alignment.tracking import Tracker


def check_params(base, params, overrides, what):
    """Return ``params`` (``None``: ``base``) with ``overrides``; every key of ``base``."""
    p = dict(base if params is None else params)
    p.update(overrides)
    missing, unknown = sorted(set(base) - set(p)), sorted(set(p) - set(base))
    if missing or unknown:
        raise ValueError('%s parameters: missing %s, unknown %s'
                         % (what, missing or 'none', unknown or 'none'))
    return p


def axes_down(names, driver_active):
    """Return the names of the axes whose driver is not driving (``driver_active`` False)."""
    if driver_active is None:
        return []
    if driver_active is True or driver_active is False:
        return [] if driver_active else list(names)
    return [a for a, up in zip(names, driver_active) if up is False]


class Machine:
    """Commands, state entry, faults and events of an alignment sequencer (SI: s, m)."""

    #: True while SEARCHING or PEAKING was entered by the machine itself (the resume
    #: after a HELD): a command then replaces it instead of being refused as busy
    _resumed = False

    #: the axes' names in the order of ``sp`` and the positions (for the fault texts)
    AXIS_NAMES = ()
    #: TRACKING's dithers: (parameter naming the frequency (Hz), axes of its sine or circle)
    DITHERS = ()
    #: the parameter naming the dither's amplitude (m): a sine's, a circle's radius
    DITHER_AMPLITUDE = 'dither_radius_m'
    #: True: the tracker pairs each reading with the positions ``power_lag_s`` earlier
    TRACK_LAG = True

    def _init_machine(self, p):
        """Set the state every machine starts with (parameters ``p``, SI)."""
        self.p = p
        self._last = {'p': None, 'y': None}     # time of the last reading of each (s)
        self._prev_pos = None
        #: the power reading that has not changed: (W, since s, positions m, moved m)
        self._frozen = None
        self.state = IDLE
        self.fault_reason = ''
        self.events = []
        self.aligned_power_w = self.threshold_w = self.floor = self.first_light_t = None
        self.peak_samples = self.search_samples = self.iterations = 0
        self.dt = 0.0
        self._t = self._follow_since = None
        self._idle_buf = []
        self._phase = ''
        self._driver_up = True
        #: the one HELD law (:mod:`fiber_align.alignment.hold`)
        self.hold = Hold(p['settle_tolerance_m'], p['settle_samples'],
                         p['driver_down_timeout_s'], self._log)
        self._enter(IDLE)

    def align(self):
        """Start a full alignment (search, peak, track); return ``(ok, message)``."""
        if self.state in (SEARCHING, PEAKING) and not self._resumed:
            return False, 'busy: already %s' % self.state
        why = self.drivers.refusal('align')
        if why:
            return False, why
        self.fault_reason = ''
        self._resumed = False
        if self.state != IDLE:
            # the IDLE readings were taken at the park position, at rest: from anywhere
            # else (TRACKING, HELD, FAULT, a re-plug) the floor is measured afresh
            self._idle_buf = []
        self._enter(SEARCHING)
        self._start_search()
        return True, 'alignment started'

    def release(self):
        """Park and go IDLE; clears a FAULT. Return ``(ok, message)``."""
        self.fault_reason = ''
        self._enter(RELEASING)
        return True, 'releasing to %s' % self._park_text()

    def switch(self, on):
        """Switch the light on (the last aligned point, re-peak, track) or off (park)."""
        if self.state == FAULT:
            return False, 'in FAULT (%s); call release%s' % (self.fault_reason,
                                                             ' or align' if on else '')
        if not on:
            self._enter(RELEASING)
            return True, 'switching off'
        if self.state in (SEARCHING, PEAKING) and not self._resumed:
            return False, 'busy: %s' % self.state
        if self.state == TRACKING:
            return True, 'already on'
        if self.aligned is None:
            return False, 'no aligned position yet: call align first'
        why = self.drivers.refusal('switch on')
        if why:
            return False, why
        self._resumed = False
        self._enter(PEAKING)
        return True, self._start_repeak()

    # ---- what the drivers publish (DriverState's rules) -----------------------------
    def driver_held(self, held, name=None):
        """Take a driver's latched ``drive_held`` (bool); return True when the machine acted."""
        return self._driver_news(self.drivers.held(held, name))

    def driver_lifecycle(self, state, name=None):
        """Take the goal state of a driver's ``~/transition_event``; True when it acted."""
        return self._driver_news(self.drivers.lifecycle(state, name))

    def driver_diagnostics(self, ok, name=None):
        """Take a driver's ``/diagnostics`` (``ok``: below ERROR); True when it acted."""
        return self._driver_news(self.drivers.diagnostics(ok, name))

    def driver_gone(self, name=None):
        """Note that a driver's ``drive_held`` publisher vanished; True when it acted."""
        return self._driver_news(self.drivers.gone(name))

    def _driver_news(self, changed):
        d = self.drivers
        if changed and self.state in ACTIVE and d.active is False and not d.pending:
            self._driver_down(d.reason)
            return True
        return False

    def _driver_down(self, reason):
        """Hold at once: a driver stopped driving (what the drivers published)."""
        self._hold(reason, self._down_names(self.drivers.each))

    @property
    def setpoint(self):
        """Return the last setpoints (m), one per axis."""
        return tuple(self.sp.tolist())

    def _down_names(self, driver_active):
        return axes_down(self.AXIS_NAMES, driver_active)

    def _update(self, t_s, positions_m, power_w, driver_active):
        """
        Advance one control period (every machine's); return the setpoints (m).

        :param positions_m: the measured positions (m), or None (or a None in them).
        :param driver_active: None (as the drivers published), a bool for every driver,
            or one bool per axis: False when that driver is not driving (HELD).
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
        if driver_active is None:
            driver_active = self._driver_input()     # what the drivers published
        down = self._down_names(driver_active)
        self._driver_up = not down
        if self.state in ACTIVE and down:
            self._hold(self.drivers.reason, down)
        if self.state in ACTIVE and self._silent_or_stuck(t, pos, pw):
            return self.setpoint
        if pos is None:
            pos = self._prev_pos if self._prev_pos is not None else self.sp.copy()
        tol = self.p['settle_tolerance_m']     # plain floats: numpy's cost on three values
        self._rest = self._prev_pos is not None and all(
            abs(a - b) < tol for a, b in zip(pos.tolist(), self._prev_pos.tolist()))
        self._prev_pos = pos
        getattr(self, '_do_' + self.state.lower())(t, self._handler_pos(pos), pw)
        if self.state == PEAKING:
            self.peak_samples += 1
        elif self.state == SEARCHING:
            self.search_samples += 1
        self.sp = np.minimum(np.maximum(self.sp, self.lo), self.hi)
        return self.setpoint

    def _handler_pos(self, pos):
        return pos                          # the states' steps take the positions (m)

    # ---- HELD (the machine's Hold) ---------------------------------------------------
    @property
    def hold_reason(self):
        """Return why the machine is HELD ('' when it is not)."""
        return self.hold.reason if self.state == HELD else ''

    def _hold(self, why='', down=()):
        """Enter HELD from an active state: keep the setpoints, say why."""
        state, center = self.state, self._hold_center()
        self._enter(HELD)
        self._phase = 'down'
        named = down if len(self.AXIS_NAMES) > 1 else ()        # one axis: no name
        self._log(self.hold.enter(self._t, state, self.sp, center, named, why))

    def _do_held(self, t, pos, pw):
        self.sp = self.hold.setpoint.copy()
        nxt, text = self.hold.step(t, pos, pw, self._driver_up, self.threshold_w)
        self._phase = self.hold.phase
        if nxt == FAULT:
            self._fault(text)
        elif nxt == SEARCHING:
            self._search_again(text)
        elif nxt == PEAKING:
            self._resumed = True            # align and switch replace this re-peak
            self._repeak_after_hold(t, self.hold.center)

    def _search_again(self, why):
        self._log('%s: searching again' % why)
        self._resumed = True                # align and switch replace this resume
        self._idle_buf = []                 # not at the park position: a fresh floor
        self._enter(SEARCHING)
        self._start_search()

    # ---- TRACKING (the one tracker) --------------------------------------------------
    def _curvatures(self):
        """Return ``k`` of ``ln P`` (1/m^2): one for every axis, or one per axis."""
        return self.curvature_per_m2

    def _start_tracking(self, t):
        """TRACKING from the aligned point (m): the dithers of ``DITHERS``."""
        p = self.p
        self._enter(TRACKING)
        self._tracker = Tracker(self.aligned, self._curvatures(), p[self.DITHER_AMPLITUDE],
                                [(p[key], axes) for key, axes in self.DITHERS], t, p,
                                self.lo, self.hi, self.aligned_power_w,
                                p['power_lag_s'] if self.TRACK_LAG else 0.0)

    def _do_tracking(self, t, pos, pw):
        sp = self._tracker.step(t, self.dt, pos, pw)
        if sp is None:
            self._fault(self._tracker.loss.fault)
        else:
            self.aligned = self._tracker.xhat.copy()
            self.sp = sp

    def _silent_or_stuck(self, t, pos, pw):
        """Return True (and fault) when a reading is missing or frozen, or an axis is stuck."""
        p = self.p
        t0 = self._state_t if self._state_t is not None else t
        for key, what in (('p', None), ('y', 'displacement')):
            last = max(self._last[key] if self._last[key] is not None else t0, t0)
            if t - last > p['sensor_timeout_s']:
                self._fault('sensor silent: no %s reading for %.0f ms'
                            % (what or self._power_text(), (t - last) * 1e3))
                return True
        if pos is None:
            return False
        frozen = self._meter_frozen(t, pos, pw)
        if frozen:
            self._fault(frozen)
            return True
        fe = p['follow_error_m']
        if any(abs(a - b) > fe for a, b in zip(pos.tolist(), self.sp.tolist())):
            err = np.abs(pos - self.sp)
            if self._follow_since is None:
                self._follow_since = t
            elif t - self._follow_since > p['follow_timeout_s']:
                a = int(np.argmax(err))
                self._fault('driver inactive or actuator stuck: %s at %.1f um does not '
                            'follow its setpoint %.1f um for %.0f ms'
                            % (self.AXIS_NAMES[a], pos[a] * 1e6, self.sp[a] * 1e6,
                               (t - self._follow_since) * 1e3))
                return True
        else:
            self._follow_since = None
        return False

    def _power_text(self):
        """Return what a silent power reading is called in a fault (the array: which meter)."""
        return 'optical power'

    def _meter_frozen(self, t, pos, pw):
        """
        Return why the power meter is frozen (text), or '' while its reading can be live.

        A constant reading is normal in the dark (a meter that clamps at its floor, a
        quantised reading): at or below ``dark_floor_w`` or the first-light threshold it is
        never suspect. With light present the reading cannot stay the same to the last bit
        while the axes move: more than ``settle_tolerance_m`` from where it last changed,
        for longer than ``meter_frozen_timeout_s`` (s), the meter is frozen.
        """
        fr, p = self._frozen, self.p
        dark = max(p['dark_floor_w'], self.threshold_w or 0.0)
        if pw is None:
            return ''
        if fr is None or pw != fr[0] or pw <= dark:
            self._frozen = (pw, t, pos.copy(), 0.0)
            return ''
        moved = max(fr[3], float(np.max(np.abs(pos - fr[2]))))
        self._frozen = fr[:3] + (moved,)
        if moved > p['settle_tolerance_m'] and t - fr[1] > p['meter_frozen_timeout_s']:
            return ('power meter frozen: the optical power reading stays at %.6g W (%.1f dBm, '
                    'light present) for %.0f ms while %s moved %.2f um: the meter does not '
                    'measure; check the power meter and its link'
                    % (pw, dbm(pw), (t - fr[1]) * 1e3,
                       'the actuator' if len(pos) == 1 else 'the axes', moved * 1e6))
        return ''

    # ---- SEARCHING: the floor at rest ------------------------------------------------
    def _measure_floor(self, rest, pw):
        """
        Add a reading at rest to the floor; return None until there are enough (or FAULT).

        Then set ``floor`` and ``threshold_w`` and return True when light is present at
        the start (a floor above ``floor_max_w``), else False.
        """
        p = self.p
        if rest and pw is not None:
            self._floor_buf.append(pw)
        n = int(p['floor_samples'])
        if len(self._floor_buf) < n:
            return None
        f = np.asarray(self._floor_buf[-n:])
        mean, std = float(f.mean()), float(f.std(ddof=1))
        if np.ptp(f) <= 1e-9 * abs(mean):
            # a constant floor is the meter's (a clamp, a quantised reading), not a dead
            # sensor: no noise can be seen below its level, so the level stands for it
            # (at least dark_floor_w); a frozen meter shows where light is: _meter_frozen
            std = max(abs(mean), p['dark_floor_w'])
            self._log('constant reading %.3g W at rest: the meter\'s floor or resolution' % mean)
        self.floor = (mean, std)
        if mean > p['floor_max_w']:
            self.threshold_w = p['floor_max_w']
            self._log('light present at the start (%.1f dBm)' % dbm(mean))
            return True
        self.threshold_w = max(mean + p['threshold_sigma'] * std, p['min_threshold_w'])
        return False

    def _enter(self, state):
        """Enter ``state`` at the time of the last update; reset its counters."""
        self.state = state
        self._resumed = self._resumed and state in (SEARCHING, PEAKING)
        self._state_t = self._t
        self._follow_since = None
        if state not in ACTIVE:
            self._frozen = None             # a frozen reading is judged while active only
        if state == PEAKING:
            self.peak_samples = 0
            self.iterations = 0
        if state == SEARCHING:
            self.search_samples = 0
        if state == IDLE:
            self._idle_buf = []
        self.events.append((self._t, state, self.fault_reason))

    def _log(self, text):
        self.events.append((self._t, self.state, text))

    def _fault(self, reason):
        self.fault_reason = reason
        self._enter(FAULT)

    def _elapsed(self, t):
        """Return the time (s) since the state was entered (0 before any update)."""
        return t - (self._state_t if self._state_t is not None else t)

    def _do_fault(self, t, pos, pw):
        pass  # hold the setpoints; release() parks

    def _park_text(self):
        return um(self.park)

    def _do_idle(self, t, pos, pw):
        """At the park position: readings at rest count towards the floor of the next align."""
        self.sp = self.park.copy()
        if not self._rest:
            self._idle_buf = []
        elif pw is not None:
            self._idle_buf.append(pw)
            del self._idle_buf[:-int(self.p['floor_samples'])]

    def _do_releasing(self, t, pos, pw):
        self.sp = self.park.copy()
        if np.all(np.abs(pos - self.park) < self.p['release_tolerance_m']) or \
                self._elapsed(t) > self.p['release_timeout_s']:
            self._enter(IDLE)
