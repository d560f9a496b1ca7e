# SPDX-License-Identifier: Apache-2.0
"""
The realtime setpoint trajectory the compensator and controller nodes share (m, m/s, s).

Pure Python (header stamps are read as ``stamp.sec`` / ``stamp.nanosec``), with the
setpoint check the nodes apply to every setpoint they take.
"""

import math

#: Realtime: default rate limit (m/s) of the setpoint trajectory (see
#: :class:`SetpointTrajectory`). Used when the params files do not set
#: ``realtime_setpoint_rate_m_per_s``; 2 mm/s moves 50 um in 25 ms and leaves the paper's
#: references (0.75 Hz sine, 1 Hz triangle over 82 um: at most 0.19 mm/s) untouched.
REALTIME_SETPOINT_RATE_M_PER_S = 2e-3
#: Realtime: at most this many skipped samples are caught up one by one; a node that
#: finds a longer gap between the samples it processes (it was stalled for more than
#: 50 ms at 1 kHz, as long as the driver's default watchdog timeout) cannot know what
#: the output did meanwhile and restarts at rest at the measured position.
MAX_CATCH_UP = 50
#: Realtime: the loop is open while the newest ``drive_voltage`` is older than this many
#: periods (the driver is stalled): the controller holds its output, and the compensator
#: and the controller hold the trajectory, so both go on from there when the drive does.
DRIVE_STALE_PERIODS = 3


def stamp_ns(stamp):
    """Return a builtin_interfaces/Time as integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class SetpointTrajectory:
    """
    Realtime setpoint trajectory, advanced by sample index (m, m/s, s).

    A rate-limited path from the present value to the latest setpoint: each sample it
    moves at most ``rate_m_per_s * period_s`` towards the target (a step becomes a ramp;
    ``rate_m_per_s`` <= 0: no limit). The compensator and the controller run the same
    trajectory. The controller advances it by the number of sample periods between the
    stamps of the displacement samples it processes (:meth:`periods`), so its reference
    model stays on the time line; the compensator advances it one period per sample
    it answers: catching a stall up at once made its feedforward jump (the
    ``hysteresis_compensator`` docstring). A ramp also keeps each missed cycle of a non-realtime OS
    a small disturbance; a step through the resonance shaper is a 2-3 sample burst that
    a missed cycle turns into an unshaped jump (the bending mode has 3 % damping).
    """

    def __init__(self, period_s, rate_m_per_s):
        """Store the period (s) and the rate limit (m/s); start at rest at 0 m."""
        self.period_ns = int(round(float(period_s) * 1e9))
        rate = float(rate_m_per_s)
        self.step_m = rate * float(period_s) if rate > 0 and math.isfinite(rate) else math.inf
        self.value = 0.0
        self.last_ns = None

    def reset(self, value):
        """Rest at ``value`` (m)."""
        self.value = float(value)

    def periods(self, stamp):
        """Return how many sample periods, at least 1, lie between the last two stamps."""
        ns = stamp_ns(stamp)
        last, self.last_ns = self.last_ns, ns
        if last is None:
            return 1
        n = int(round((ns - last) / self.period_ns))
        return n if n >= 1 else 1

    def advance(self, target, n=1):
        """
        Advance ``n`` periods towards ``target`` (m); return the values (m).

        One value per period, at most :data:`MAX_CATCH_UP` (the last ones).
        """
        out = []
        v, d = self.value, self.step_m
        if n > MAX_CATCH_UP:        # a long gap: jump over the first periods at once
            gap = d * (n - MAX_CATCH_UP)
            v = min(target, v + gap) if target >= v else max(target, v - gap)
            n = MAX_CATCH_UP
        for _ in range(n):
            if target > v + d:
                v += d
            elif target < v - d:
                v -= d
            else:
                v = target
            out.append(v)
        self.value = v
        return out


def check_setpoint(value, lo, hi):
    """
    Return ``None`` when the setpoint ``value`` (m) is usable, else the reason (str).

    :param lo: lowest allowed setpoint (m).
    :param hi: highest allowed setpoint (m).
    """
    try:
        v = float(value)
    except (TypeError, ValueError):
        return 'setpoint %r is not a number' % (value,)
    if math.isnan(v):
        return 'setpoint is NaN'
    if math.isinf(v):
        return 'setpoint is %s' % ('+inf' if v > 0 else '-inf')
    if v < lo or v > hi:
        return 'setpoint %.6g m is outside [%.6g, %.6g] m' % (v, lo, hi)
    return None


class Setpoint:
    """
    The latest valid setpoint (m) of a node, and the count of rejected ones.

    :param lo: lowest allowed setpoint (m); :param hi: highest (m).
    """

    def __init__(self, lo, hi):
        """Start at 0 m with nothing rejected."""
        self.lo, self.hi = float(lo), float(hi)
        self.value = 0.0
        self.rejected = 0

    def take(self, value):
        """Return ``None`` when ``value`` (m) is now the setpoint, else why not (str)."""
        why = check_setpoint(value, self.lo, self.hi)
        if why is None:
            self.value = float(value)
            return None
        self.rejected += 1
        return 'rejected %s; holding %.6g m' % (why, self.value)
