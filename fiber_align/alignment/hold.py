# SPDX-License-Identifier: Apache-2.0
"""
HELD, one law for every sequencer: a driver holds its output, the sequencer waits for it.

A driver that holds its output (a watchdog trip, ``enable`` false, an inactive or
unconfigured lifecycle node: ``drive_held`` true) while a sequencer is SEARCHING, PEAKING
or TRACKING does not end the alignment. The sequencer enters HELD: every axis keeps its
last setpoint (the dithers stop too), ``hold_reason`` and an event say why, and it waits.
Once every driver drives again (the re-arm) and every axis is back at its held setpoint
(within ``settle_tolerance_m`` for ``settle_samples`` readings in a row, the machine's own
settling rule) with a power reading:

- nothing to re-peak from (held while SEARCHING) or no light at the held point (a reading
  at or below the first-light threshold: the slot moved, the source went off): search
  again;
- else re-peak from there, the machine's own choice (1-D: the first sweep goes on with
  the readings before the trip, or a local re-peak; 2-D and station: a pattern around the
  last estimate), then TRACKING.

FAULT when the drivers stay down longer than ``driver_down_timeout_s`` (s), or the axes are
not back that long after the re-arm; a driver down again while they return restarts the
wait. :class:`Hold` is owned by the machine (``machine.Machine.hold``): it keeps its own
state and says what to do next; the machine does it. SI units: s, m, W.
"""

import numpy as np

from fiber_align.alignment.states import FAULT, PEAKING, SEARCHING, um


class Hold:
    """
    The HELD state over a set of axes (module docstring).

    :param tolerance_m: an axis is back when within this of its held setpoint (m) ...
    :param samples: ... for this many readings in a row.
    :param timeout_s: longest wait for the re-arm, and for the return after it (s).
    :param log: called with the text of each event (the machine's event log).
    """

    def __init__(self, tolerance_m, samples, timeout_s, log):
        """Start out of HELD (no reason)."""
        self.tolerance_m = float(tolerance_m)
        self.samples = int(samples)
        self.timeout_s = float(timeout_s)
        self.log = log
        self.reason = ''
        self.held_from = self.center = self.setpoint = None
        self.phase, self.since, self.count, self.why = '', None, 0, ''

    def enter(self, t, state, setpoint, center, down=(), why=''):
        """
        Enter HELD at ``t`` (s) from ``state``; return the reason (text).

        :param setpoint: the setpoints to hold (m).
        :param center: what the machine re-peaks from (its type is the machine's), or
            ``None``: the re-arm searches again.
        :param down: names of the axes whose driver is down (named when several).
        :param why: what the drivers' messages say of it, or ''.
        """
        self.held_from, self.center = state, center
        self.setpoint = np.array(setpoint, dtype=float).reshape(-1)
        self.phase, self.since, self.count, self.why = 'down', t, 0, why
        self.reason = ('driver%s down during %s at %s%s: setpoints held, waiting for the '
                       're-arm (enable or a lifecycle cycle), FAULT after %.1f s'
                       % (' of ' + ', '.join(down) if down else '', state, um(self.setpoint),
                          ' (%s)' % why if why else '', self.timeout_s))
        return self.reason

    def step(self, t, pos, pw, driver_up, threshold_w):
        """
        Advance one period; return ``(state, text)``: what the machine does next.

        ``(None, '')``: stay HELD; ``(FAULT, why)``; ``(SEARCHING, why)``: search again;
        ``(PEAKING, '')``: re-peak from :attr:`center`.

        :param pos: the measured positions (m).
        :param pw: the power reading (W), or None.
        :param driver_up: False while a driver is down.
        :param threshold_w: the first-light threshold (W), or None.
        """
        if not driver_up:
            if self.phase != 'down':
                self.phase, self.since = 'down', t
                self.log('driver down again while returning: setpoints held')
            if t - self.since > self.timeout_s:
                return FAULT, ('driver inactive: a driver held its output for more than '
                               '%.1f s (since %.3f s, during %s at %s) without a re-arm '
                               '(enable or a lifecycle cycle)%s; release or align once it '
                               'drives' % (self.timeout_s, self.since, self.held_from,
                                           um(self.setpoint),
                                           ': %s' % self.why if self.why else ''))
            return None, ''
        if self.phase == 'down':
            self.log('%s back after %.0f ms' % ('driver' if self.setpoint.size == 1
                                                else 'drivers', (t - self.since) * 1e3))
            self.phase, self.since, self.count = 'return', t, 0
        err = np.abs(np.asarray(pos, dtype=float).reshape(-1) - self.setpoint)
        self.count = self.count + 1 if np.all(err < self.tolerance_m) else 0
        if self.count >= self.samples and pw is not None:
            self.reason = ''
            if self.center is None:
                return SEARCHING, 'no light before the trip'
            if threshold_w is not None and pw <= threshold_w:
                return SEARCHING, ('no light at the held point %s after the re-arm'
                                   % um(self.setpoint))
            return PEAKING, ''
        if t - self.since > self.timeout_s:
            return FAULT, ('actuator does not return to the held setpoint %s after the '
                           're-arm (at %s)' % (um(self.setpoint), um(pos)))
        return None, ''
