# SPDX-License-Identifier: Apache-2.0
"""
The realtime step rules of the control loop's nodes, beside the laws they drive.

Pure: the nodes pass the clock readings (s, monotonic) and the messages' values (m, V);
these classes decide what one step does. SI units throughout.
"""

import math

from fiber_align.control.trajectory import DRIVE_STALE_PERIODS, MAX_CATCH_UP
from fiber_align.control.trajectory import SetpointTrajectory

#: Periods of delay the realtime loop adds to the lockstep loop: the plant latches the
#: drive at its next tick (``simulated_actuator``), so the command computed from y_k
#: first acts over [t_k+1, t_k+2] instead of [t_k, t_k+1].
REALTIME_EXTRA_DELAY_PERIODS = 1


def extend_lead(obj, period_s, periods=REALTIME_EXTRA_DELAY_PERIODS):
    """
    Lengthen the delay compensation of ``obj`` by the realtime loop's extra delay.

    ``obj`` is a :class:`~fiber_align.control.feedforward.Feedforward` or a
    :class:`~fiber_align.control.shaping.ReferenceModel`; its ``lead``
    (:class:`~fiber_align.control.shaping.Lead`, if any) predicts smooth references over
    the shaper delay plus one period; in realtime the drive acts ``periods`` periods
    later still, so the horizon grows by ``periods * period_s`` (s). Returns ``obj``.
    """
    lead = getattr(obj, 'lead', None) if obj is not None else None
    if lead is not None:
        lead.lead_s += periods * float(period_s)
    return obj


def head_lead(obj, target):
    """
    Bound the delay-compensation lead of ``obj`` by the path's ``target`` (m).

    ``obj`` as in :func:`extend_lead`; the lead then never predicts past ``target``
    (:attr:`~fiber_align.control.shaping.Lead.toward`), where the realtime path stops.
    """
    lead = getattr(obj, 'lead', None) if obj is not None else None
    if lead is not None:
        lead.toward = target


def present(y):
    """Return a measured position ``y`` (m) usable as a rest position: finite, >= 0 m."""
    return max(0.0, float(y)) if math.isfinite(y) else 0.0


class LoopClock:
    """
    The realtime inputs every loop node tracks: held drive, drive age, latest position.

    The drive's age is counted in the samples this node answered since the newest
    ``drive_voltage``, not in wall time: the compensator and the controller answer the
    same samples and hear the same drives, so they judge it alike, and their paths wait
    or advance together (a wall-clock age read a few microseconds apart split them after
    a late tick of about :data:`DRIVE_STALE_PERIODS` periods).

    :param period_s: control period (s).
    :param rate_m_per_s: rate limit of the setpoint trajectory (m/s; <= 0: none).
    :param accel_m_per_s2: its acceleration limit (m/s^2; <= 0: none).
    """

    def __init__(self, period_s, rate_m_per_s, accel_m_per_s2=0.0):
        """Start at rest at 0 m, the drive passed and never heard."""
        self.period_s = float(period_s)
        self.traj = SetpointTrajectory(period_s, rate_m_per_s, accel_m_per_s2)
        self.held = False           # the driver holds its output (``drive_held``)
        self.heard = False          # a ``drive_voltage`` was heard
        self.unanswered = 0         # samples answered since the newest ``drive_voltage``
        self.y_latest = 0.0         # newest measured position (m)

    def drive(self):
        """Note a ``drive_voltage`` arriving."""
        self.heard = True
        self.unanswered = 0

    def drive_stale(self, never=True):
        """
        Return True when more than :data:`DRIVE_STALE_PERIODS` samples went unanswered.

        Counts the sample being answered (call once per sample, from ``sample``).

        :param never: the answer while no drive has been heard yet.
        """
        self.unanswered += 1
        if not self.heard:
            return never
        return self.unanswered > DRIVE_STALE_PERIODS

    def present(self):
        """Return the latest measured position (m), finite and at least 0 m."""
        return present(self.y_latest)


class CompensatorStep(LoopClock):
    """
    The compensator's realtime step: one feedforward (V) per answered sample.

    The drive held, or a gap of more than :data:`MAX_CATCH_UP` periods (this node was
    stalled and may have missed ``drive_held``): rest at the present position. More than
    :data:`DRIVE_STALE_PERIODS` samples without a drive (a stalled driver): the last
    feedforward again and the trajectory waits. Else one trajectory period per answered
    sample, whatever the gap: a stall delays the move, never jumps it. The drive's age is
    counted in samples (:class:`LoopClock`).

    :param ff: the :class:`~fiber_align.control.feedforward.Feedforward` (``step(r)``,
        ``start_at(y)``: V from m); :attr:`ff` may be replaced (a model reload).
    """

    def __init__(self, ff, period_s, rate_m_per_s, accel_m_per_s2=0.0):
        """Wrap ``ff``; start at rest at 0 m with 0 V published."""
        super().__init__(period_s, rate_m_per_s, accel_m_per_s2)
        self.ff = ff
        self.ff_last = 0.0

    def sample(self, stamp, y, target):
        """
        Answer one ``displacement`` sample; return the feedforward (V).

        :param stamp: its header stamp (counts the sample periods).
        :param y: its position (m) or ``None``.
        :param target: the latest valid setpoint (m).
        """
        if y is not None:
            self.y_latest = y
        n = self.traj.periods(stamp)
        stale = self.drive_stale(never=False)
        if self.held or n > MAX_CATCH_UP:
            v = self.rest(self.present())
        elif stale:
            v = self.ff_last
        else:
            r = self.traj.advance(target, 1)[0]
            # a ramp stops at its target: no lead past it (a stream is led freely)
            head_lead(self.ff, target if self.traj.ramping else None)
            v = self.ff.step(r)
        self.ff_last = v
        return v

    def rest(self, y):
        """Rest at ``y`` (m): feedforward and trajectory; return the feedforward (V)."""
        self.traj.reset(y)
        return self.ff.start_at(y)


#: Periods after the realtime path reached its setpoint during which the feedback's
#: integral still holds (it held during the path's ramp): the plant arrives one to a few
#: periods after the path, later when the compensator skipped samples.
INTEGRAL_SETTLE_PERIODS = 10
#: Time constant (s) with which the feedback's integral fades while the realtime path
#: ramps to a new setpoint (smoothly: a drop at once would be a step of the drive).
INTEGRAL_RAMP_FADE_S = 0.01

#: What a parked controller publishes: (feedback V, error m, error rate m/s, gains).
PARKED = (0.0, math.nan, 0.0, (0.0, 0.0, 0.0))


class ControllerStep(LoopClock):
    """
    The controller's realtime step: one feedback (V) per answered sample.

    Parked (0 V, integral cleared, reference model and trajectory at the measured
    position) while the drive is held or before the first setpoint, so every resume is
    bumpless; a gap of more than :data:`MAX_CATCH_UP` periods clears the stale integral
    and parks. The drive stale: the output held, nothing integrated, the trajectory and
    reference model wait. Else the trajectory advances one period per answered sample,
    as :class:`CompensatorStep`'s (a late sample delays the path, never jumps it), and
    the reference model gets its value one sample old (the realtime loop's extra delay)
    for each period since the last sample: over the skipped periods the value the path
    waited at.

    :param ctl: the feedback law (``step(r, y)``, ``reset()``, ``u``, ``gains``,
        ``pid``, ``reference_filter``) or ``None``; :attr:`ctl` may be replaced.
    """

    def __init__(self, ctl, period_s, rate_m_per_s, accel_m_per_s2=0.0):
        """Wrap ``ctl``; start parked, without a setpoint."""
        super().__init__(period_s, rate_m_per_s, accel_m_per_s2)
        self.ctl = ctl
        self.r_prev = 0.0           # the trajectory's value one sample old (m)
        self.has_setpoint = False
        self.settle = 0             # periods the integral still waits after a ramp

    def park(self):
        """Rest at the latest measured position (trajectory and reference model)."""
        y = self.present()
        self.traj.reset(y)
        self.r_prev = y
        rf = getattr(self.ctl, 'reference_filter', None)
        if rf is not None:
            rf.reset_to(y)

    def reset(self):
        """Clear the law's integral and filters and park."""
        if self.ctl is not None:
            self.ctl.reset()
        self.park()

    def set_held(self, held):
        """Note that the driver holds (True) or passes its output (clear the law on a hold)."""
        if held and not self.held and self.ctl is not None:
            self.ctl.reset()
        self.held = bool(held)

    def setpoint(self):
        """Note a valid setpoint; return True for the first (the law then starts parked)."""
        if self.has_setpoint:
            return False
        self.has_setpoint = True
        self.reset()
        return True

    def sample(self, stamp, y, target):
        """
        Answer one ``displacement`` sample; return ``(fb V, e m, de m/s, gains)``.

        :param stamp: its header stamp; :param y: its position (m);
        :param target: the latest valid setpoint (m).
        """
        self.y_latest = y
        n = self.traj.periods(stamp)
        stale = self.drive_stale()
        if n > MAX_CATCH_UP and self.ctl is not None:
            self.reset()
            n = 1
        if self.held or not self.has_setpoint:
            if self.held:
                self.park()
            return PARKED
        if stale:
            ctl = self.ctl
            return (ctl.u if ctl is not None else 0.0, math.nan, 0.0,
                    getattr(ctl, 'gains', (0.0, 0.0, 0.0)))
        # one path period per answered sample, as the compensator's path: the feedforward
        # and the reference follow one path, or the feedback pushes against the
        # feedforward by their difference after every late sample. Over the periods the
        # sample skipped the path waited (as the plant's drive did): the reference model
        # is stepped over them at the path's value.
        seq = [self.r_prev] * n + self.traj.advance(target, 1)
        self.r_prev = seq[-1]
        pid = getattr(self.ctl, 'pid', None)
        if pid is not None:
            # the path's own ramp to a setpoint, and a few periods after: the plant lags
            # it by the loop's delay (and the compensator's path by its skipped samples),
            # which the integral would learn and give back past the setpoint at the end.
            # During the ramp the integral also fades: it corrected the model's error at
            # the setpoint left behind, not at the one ahead (a flood of reversals kept
            # an old correction of several volts to the bottom of the range).
            if self.traj.value != target:
                self.settle = INTEGRAL_SETTLE_PERIODS
                pid.integral *= math.exp(-n * self.period_s / INTEGRAL_RAMP_FADE_S)
            else:
                self.settle = max(0, self.settle - n)
            pid.hold_integral = self.settle > 0
        rf = getattr(self.ctl, 'reference_filter', None)
        if rf is not None:
            head_lead(rf, target if self.traj.ramping else None)     # as CompensatorStep
            for r in seq[:-2]:
                rf.step(r)
        return self.step(seq[-2], y)

    def step(self, r, y):
        """One period of the law: ``(fb V, e m, de m/s, gains)`` (lockstep too)."""
        ctl = self.ctl
        if ctl is None:
            return 0.0, r - y, 0.0, (0.0, 0.0, 0.0)
        fb = ctl.step(r, y)
        return fb, r - y, ctl.pid.deriv, ctl.gains


#: Uninterrupted fresh input (s, wall) the driver waits for before it ends a trip.
RECOVERY_S = 0.02


class DriverStep:
    """
    The driver's realtime input rules: which input makes a drive command, and with what.

    A feedback makes one (with the newest feedforward). A feedforward makes one only
    while the feedback is late (a stalled controller: more than 1.5 periods, less than
    the watchdog timeout): then the drive follows the feedforward with the last feedback,
    the watchdog counting from that feedback's time. No command while the feedforward is
    older than the watchdog timeout (left to the watchdog), while the watchdog is latched,
    or after a trip until the input has been fresh for :data:`RECOVERY_S`.

    :param core: the :class:`~fiber_align.control.driver.DriverCore` (``timeout``,
        ``tripped``, ``latched``).
    :param period_s: control period (s).
    :param note: called with a line for the log when the input is back after a trip.
    """

    def __init__(self, core, period_s, note=None):
        """Start with no input heard."""
        self.core = core
        self.period_s = float(period_s)
        self.note = note
        self.t_ff = self.t_fb = None    # monotonic s of the newest feedforward, feedback
        self.ff_latest = 0.0            # newest feedforward (V)
        self.fb_last = 0.0              # newest feedback (V)
        self.t_fresh = None             # start (s) of fresh input after a trip
        self.t_fresh_last = 0.0

    def feedforward(self, v, now, enabled, sensorless=False):
        """
        Take a feedforward voltage (V) at ``now`` (s); return the command or None.

        :param enabled: the output is enabled (``~/enable``).
        :param sensorless: no feedback exists: every feedforward is a command (fb 0 V).
        """
        self.ff_latest, self.t_ff = v, now
        if sensorless:
            return self.gate(0.0, None, now, enabled)
        core, t_fb = self.core, self.t_fb
        if t_fb is not None and not core.tripped \
                and 1.5 * self.period_s < now - t_fb < core.timeout:
            return self.gate(self.fb_last, t_fb, now, enabled)
        return None

    def feedback(self, v, now, enabled):
        """Take a feedback voltage (V) at ``now`` (s); return the command or None."""
        self.t_fb, self.fb_last = now, v
        return self.gate(v, None, now, enabled)

    def gate(self, fb, t_input, now, enabled):
        """Return the command ``(ff, fb, t_input)`` unless a rule holds it (``None``)."""
        core = self.core
        if core.timeout > 0 and (self.t_ff is None or now - self.t_ff > core.timeout):
            return None
        if core.latched:
            return None
        if core.tripped and enabled and not self.recovered(now):
            return None
        return self.ff_latest, fb, t_input

    def recovered(self, now):
        """Return True once fresh input has flowed for :data:`RECOVERY_S` after a trip."""
        if self.t_fresh is None or now - self.t_fresh_last > 5.0 * self.period_s:
            if self.t_fresh is None and self.note is not None:
                self.note('input is back: holding %g s before resuming' % RECOVERY_S)
            self.t_fresh = now
        self.t_fresh_last = now
        if now - self.t_fresh < RECOVERY_S:
            return False
        self.t_fresh = None
        return True

    def tripped(self):
        """Note a watchdog trip: the recovery wait starts again with the next input."""
        self.t_fresh = None
