# SPDX-License-Identifier: Apache-2.0
"""
The commands and bookkeeping the 1-D and the 2-D alignment state machines share.

:class:`Machine` is the base of :class:`~fiber_align.alignment.sequencer.Sequencer` (one
axis) and :class:`~fiber_align.alignment.sequencer2d.Sequencer2D` (two axes, and its
hill-climb baseline): the commands ``align()``, ``release()``, ``switch(on)`` (each
returns ``(ok, message)``), state entry, faults and the event log. What differs per
machine, a subclass provides:

- ``_start_search()``: after ``align`` entered SEARCHING;
- ``_start_repeak()``: after ``switch(True)`` entered PEAKING; returns the message;
- ``_aligned_point()``: the last aligned position (m), ``None`` before the first;
- ``_park_text()``: the park position for the ``release`` message (um, text);
- ``_driver_down(reason)``: a driver stopped driving in an active state (HELD or FAULT).

What the drivers publish reaches the machine through ``driver_held``,
``driver_lifecycle``, ``driver_diagnostics`` and ``driver_gone`` (the rules:
:class:`~fiber_align.alignment.driver_state.DriverState`, in ``drivers``): a driver that
stops driving in an active state leaves it at once, not at the next sample; ``align``
and ``switch(True)`` are refused while a driver is down.

Its instances hold ``state``, ``fault_reason``, ``events`` (``(t, state, text)``),
``_t`` (time of the last update, s), ``_state_t`` (time the state was entered, s) and
``drivers`` (:class:`~fiber_align.alignment.driver_state.DriverState`).
"""

from fiber_align.alignment.states import (ACTIVE, FAULT, IDLE, PEAKING, RELEASING, SEARCHING,
                                          TRACKING)


class Machine:
    """Commands, state entry, faults and events of an alignment sequencer (SI: s, m)."""

    #: True while SEARCHING or PEAKING was entered by the machine itself (the resume
    #: after a HELD): a command then replaces it instead of being refused as busy
    _resumed = False

    def align(self):
        """Start a full alignment (search, peak, track); return ``(ok, message)``."""
        if self.state in (SEARCHING, PEAKING) and not self._resumed:
            return False, 'busy: already %s' % self.state
        why = self.drivers.refusal('align')
        if why:
            return False, why
        self.fault_reason = ''
        self._resumed = False
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
        if self._aligned_point() is None:
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

    def _enter(self, state):
        """Enter ``state`` at the time of the last update; reset its counters."""
        self.state = state
        self._resumed = self._resumed and state in (SEARCHING, PEAKING)
        self._state_t = self._t
        self._follow_since = None
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
