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
#: Realtime: the loop is open while more than this many samples went without a
#: ``drive_voltage`` (the driver is stalled): the controller holds its output, and the
#: compensator and the controller hold the trajectory, so both go on from there when the
#: drive does.
DRIVE_STALE_PERIODS = 3


def stamp_ns(stamp):
    """Return a builtin_interfaces/Time as integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def stamp_to_s(stamp):
    """Return a builtin_interfaces/Time as float seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


class SetpointTrajectory:
    """
    Realtime setpoint trajectory, advanced by sample index (m, m/s, s).

    A rate- and acceleration-limited path from the present value to the latest
    setpoint: its speed is at most ``rate_m_per_s`` and changes by at most
    ``accel_m_per_s2 * period_s`` a period, and it slows down in time to stop at the
    target (never past it; a step becomes an S-shaped ramp; a limit <= 0: none). The
    acceleration limit is what keeps a client that reverses the setpoint every period
    (a flood) from reversing the path every period: at a reversal the inverse hysteresis
    model swings the drive by the width of the hysteresis loop at a rate proportional to
    the path's speed, and an abrupt reversal rang the bending mode by several
    micrometres past the commanded range. The compensator and the controller run the
    same trajectory, each one period per sample it answers: catching a stall up at once
    made the feedforward jump (the ``hysteresis_compensator`` docstring), and a
    controller whose path caught up while the compensator's did not pushed against the
    feedforward by their difference. The controller counts the sample periods between
    the stamps of the samples it processes (:meth:`periods`) for its reference model,
    which waits over the skipped periods at the path's value. A ramp also keeps each
    missed cycle of a non-realtime OS a small disturbance; a step through the resonance
    shaper is a 2-3 sample burst that a missed cycle turns into an unshaped jump (the
    bending mode has 3 % damping).
    """

    def __init__(self, period_s, rate_m_per_s, accel_m_per_s2=0.0):
        """Store the period (s), the rate (m/s) and acceleration (m/s^2) limits; rest at 0 m."""
        self.period_s = float(period_s)
        self.period_ns = int(round(self.period_s * 1e9))
        rate, accel = float(rate_m_per_s), float(accel_m_per_s2)
        self.rate = rate if rate > 0 and math.isfinite(rate) else math.inf
        self.accel = accel if accel > 0 and math.isfinite(accel) else math.inf
        self.step_m = self.rate * self.period_s
        self.value = 0.0
        self.speed = 0.0            # m/s, signed
        self.bound = None           # m: the target the path last moved towards
        self.arrived = True         # the last advance ended at its target
        #: the path ramps to a target (set by :meth:`advance`): it did not end at its
        #: target, or the advance before did not (the period of the arrival). A streamed
        #: reference that the path follows sample by sample is not a ramp.
        self.ramping = False
        self.last_ns = None

    def reset(self, value):
        """Rest at ``value`` (m), not moving."""
        self.value = float(value)
        self.speed = 0.0
        self.bound = None
        self.arrived, self.ramping = True, False

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
        v = self.value
        if n > MAX_CATCH_UP:        # a long gap: jump over the first periods at once
            gap = self.step_m * (n - MAX_CATCH_UP)
            v = min(target, v + gap) if target >= v else max(target, v - gap)
            n = MAX_CATCH_UP
        t, a, vmax, s = self.period_s, self.accel, self.rate, self.speed
        dv = a * t
        for _ in range(n):
            d = target - v
            if d == 0.0 and s == 0.0:
                out.append(v)
                continue
            dist = d if d >= 0.0 else -d
            # the fastest speed from which the path still stops at the target, slowing
            # by ``dv`` a period: m periods of m dv, (m - 1) dv, ... cover dv t m (m + 1) / 2
            want = dist / t if dv == math.inf else \
                dv * (math.sqrt(0.25 + 2.0 * dist / (dv * t)) - 0.5)
            if want > vmax:
                want = vmax
            want = want if d >= 0.0 else -want
            s = min(max(want, s - dv), s + dv)
            nv = v + s * t
            if (d >= 0.0 and nv >= target) or (d <= 0.0 and nv <= target):
                nv, s = target, 0.0     # arrived (or would pass): rest there
            elif s * d >= 0.0:
                self.bound = target
            else:                       # still slowing down for the previous target
                b = self.bound
                if b is not None and (nv - b) * (v - b) <= 0.0:
                    nv, s = b, 0.0      # never past it, whatever the rounding
            v = nv
            out.append(v)
        self.value, self.speed = v, s
        arrived = v == target
        self.ramping = not (arrived and self.arrived)
        self.arrived = arrived
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
