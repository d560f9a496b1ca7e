# SPDX-License-Identifier: Apache-2.0
"""
DriverCore: the last stage before the amplifier (step 5 of a control period).

``command(ff, fb, t)`` sums feedforward and feedback (V), clamps to ``[v_min, v_max]``
(V), limits the change since the previous output to ``slew_rate_v_per_s`` times the time
elapsed (V/s, s), and returns the drive voltage. ``tick(t)`` is the watchdog: when no
command has arrived for longer than ``watchdog_timeout_s`` it ramps the output (at the
slew limit) to ``safe_voltage_v`` and counts the event. NaN inputs hold the previous
output. Counters: ``saturation_count``, ``slew_count``, ``watchdog_count``,
``nan_count``.

The watchdog **latches** after ``latch_trips`` trips within ``latch_window_s`` seconds:
the output then stays at (ramps to) the safe voltage whatever commands arrive, until
:meth:`DriverCore.rearm` (the driver node's ``~/enable`` or a lifecycle deactivate /
activate). A loop that keeps losing its input thus stops instead of cycling between
the safe voltage and an overshooting resume.

The ramp to the safe voltage advances by at most ``ramp_period_s`` (one control
period) a call, so a caller that stalls continues its ramp by one step, never by the
whole stall at once: for the plant that would be a step down, which rings the bending
mode by its full height below the safe voltage (a driver stalled 30 ms at a time during
its ramp stepped 45-49 V at once and rang the bimorph to -17..-19 um before this cap;
``test_nodes_realtime.py``). The way back follows the command at
the slew limit: a resume ramped at the safe rate was measured worse, as the loop winds
up during the ramp (``test_nodes_realtime.py`` with two CPU hogs, 50 um setpoint: peaks
of 63.5-66.7 um after a 0.3 s stall and up to 83 um after a controller restart, 8 runs;
with the step 50.1-51.0 um and at most 52.8 um, 5 runs).
"""

import math

from fiber_align.config import ConfigError, load_params

CONFIG_FILE = 'driver.yaml'
CONFIG_NODE = 'actuator_driver'


class DriverCore:
    """
    Sum, clamp, slew-limit and watch the drive voltage (all V, V/s, s).

    :param v_min: lowest drive (V).
    :param v_max: highest drive (V).
    :param slew_rate_v_per_s: largest rate of change (V/s); <= 0 or inf for none.
    :param watchdog_timeout_s: longest silence (s) before the safe state; <= 0 disables.
    :param safe_voltage_v: drive in the safe state (V).
    """

    def __init__(self, v_min=0.0, v_max=100.0, slew_rate_v_per_s=math.inf,
                 watchdog_timeout_s=0.0, safe_voltage_v=0.0, latch_trips=3,
                 latch_window_s=10.0, safe_ramp_rate_v_per_s=math.inf, ramp_period_s=0.0):
        """
        Check and store the limits; start at ``safe_voltage_v``.

        :param latch_trips: trips within ``latch_window_s`` that latch the safe state
            (0: never latch).
        :param latch_window_s: window (s) of that count.
        :param safe_ramp_rate_v_per_s: rate (V/s) of every ramp to the safe voltage
            (watchdog, latch, disable); slow enough not to ring the bending mode, which
            a ramp at the amplifier's slew limit (a step, for the plant) rings by the
            full height of the step.
        :param ramp_period_s: the longest time (s) one step of that ramp counts: the
            control period; <= 0: no cap (each step counts the whole time elapsed).
        """
        if not v_max > v_min:
            raise ConfigError('v_max (%g V) must exceed v_min (%g V)' % (v_max, v_min))
        if not v_min <= safe_voltage_v <= v_max:
            raise ConfigError('safe_voltage_v (%g V) must lie in [v_min, v_max]'
                              % safe_voltage_v)
        self.v_min = float(v_min)
        self.v_max = float(v_max)
        s = float(slew_rate_v_per_s)
        self.slew = s if s > 0 and math.isfinite(s) else math.inf
        self.timeout = float(watchdog_timeout_s)
        self.safe = float(safe_voltage_v)
        if int(latch_trips) < 0 or not float(latch_window_s) >= 0.0:
            raise ConfigError('latch_trips must be >= 0 and latch_window_s >= 0 s')
        r = float(safe_ramp_rate_v_per_s)
        self.safe_rate = r if r > 0 and math.isfinite(r) else math.inf
        rp = float(ramp_period_s)
        self.ramp_dt = rp if rp > 0 and math.isfinite(rp) else math.inf
        self.latch_trips = int(latch_trips)
        self.latch_window_s = float(latch_window_s)
        self.reset()

    @classmethod
    def from_params(cls, p, ramp_period_s=0.0):
        """
        Build from the ``actuator_driver`` parameters (see ``config/driver.yaml``).

        :param ramp_period_s: the control period (s) of the caller (``1 / rate_hz``),
            the longest time one ramp step counts; 0: no cap.
        """
        known = {'v_min', 'v_max', 'slew_rate_v_per_s', 'watchdog_timeout_s',
                 'safe_voltage_v', 'latch_window_s', 'safe_ramp_rate_v_per_s'}
        kw = {k: float(v) for k, v in p.items() if k in known}
        if 'latch_trips' in p:
            kw['latch_trips'] = int(p['latch_trips'])
        return cls(ramp_period_s=ramp_period_s, **kw)

    @classmethod
    def from_config(cls, path=CONFIG_FILE):
        """Build from ``config/driver.yaml``."""
        return cls.from_params(load_params(path, CONFIG_NODE))

    def reset(self):
        """Output the safe voltage, forget the last command time, clear the counters."""
        self.v = self.safe
        self.t_last_cmd = None
        self.t_last_out = None
        self.t_tick = None          # the watchdog's previous tick (s)
        self.tripped = False
        self.saturated = False
        self.saturation_count = 0
        self.slew_count = 0
        self.watchdog_count = 0
        self.nan_count = 0
        self.latched = False
        self.trip_times = []

    def start_safe_ramp(self, t):
        """Start a ramp to the safe voltage at ``t`` (s) (a disable or a deactivate)."""
        self.t_last_out = t

    def ramp_safe(self, t):
        """Return the output (V) at ``t`` (s) on the way to the safe voltage (safe rate)."""
        return self._limit(self.safe, t, min(self.slew, self.safe_rate), self.ramp_dt)

    def _limit(self, target, t, rate=None, max_dt=math.inf):
        """
        Limit the move from the present output to ``target`` at ``t`` (s) to ``rate``.

        :param max_dt: the longest time (s) the move may count (a ramp: one period).
        """
        tl = self.t_last_out
        rate = self.slew if rate is None else rate
        if tl is not None and rate != math.inf:
            dv_max = rate * min(t - tl if t > tl else 0.0, max_dt)
            v = self.v
            if target > v + dv_max:
                target = v + dv_max
                self.slew_count += 1
            elif target < v - dv_max:
                target = v - dv_max
                self.slew_count += 1
        self.t_last_out = t
        self.v = target
        return target

    def command(self, ff, fb, t, t_input=None):
        """
        Return the drive (V) for feedforward ``ff`` and feedback ``fb`` (V) at ``t`` (s).

        :param t_input: the time (s) of the stalest input in this command, from which the
            watchdog counts (a command on a fresh feedforward with the last, late
            feedback: that feedback's time); default ``t``.
        """
        u = ff + fb
        self.t_last_cmd = t if t_input is None else t_input
        if self.latched:            # latched safe state: only rearm() ends it
            return self.ramp_safe(t)
        if u - u != 0.0:            # NaN or infinite
            self.nan_count += 1
            return self.v
        self.tripped = False
        if u > self.v_max:
            u = self.v_max
            self.saturated = True
            self.saturation_count += 1
        elif u < self.v_min:
            u = self.v_min
            self.saturated = True
            self.saturation_count += 1
        else:
            self.saturated = False
        return self._limit(u, t)

    def hold(self, t, t_input=None):
        """
        Take a fresh input at ``t`` (s) without following it; return the drive (V).

        For an axis held because another axis of its device tripped: its own input is
        back (its watchdog counts from ``t_input``, default ``t``; it is no longer
        tripped), but it ramps on to the safe voltage. Were it still counted as tripped,
        two axes tripped by one upstream stall would each wait for the other for ever.
        """
        self.t_last_cmd = t if t_input is None else t_input
        if not self.latched:
            self.tripped = False
        return self.ramp_safe(t)

    def tick(self, t):
        """
        Run the watchdog at time ``t`` (s); return the drive (V) to hold or ramp to.

        Call it every ``ramp_period_s`` between commands. After ``watchdog_timeout_s``
        without a command the driver enters the safe state (counted once per silence)
        and ramps to ``safe_voltage_v``. The silence counts only while the watchdog
        runs: a tick more than two periods after the previous one (the caller's process
        or the machine stalled) takes the stalled time off the inputs' age.
        """
        prev, self.t_tick = self.t_tick, t
        if self.latched:
            return self.ramp_safe(t)
        if self.timeout <= 0 or self.t_last_cmd is None:
            return self.v
        if prev is not None and t - prev > 2 * self.ramp_dt:
            # the watchdog itself did not run (its process, or the whole machine, was
            # stalled): its inputs could not be heard either, so that time is no silence
            # of theirs; they get the rest of their timeout from now
            self.t_last_cmd = min(t, self.t_last_cmd + (t - prev - self.ramp_dt))
        if t - self.t_last_cmd > self.timeout:
            if not self.tripped:
                self.tripped = True
                self.watchdog_count += 1
                self.t_last_out = t     # the ramp starts now, not at the last command
                self.trip_times = [x for x in self.trip_times
                                   if t - x <= self.latch_window_s] + [t]
                if self.latch_trips and len(self.trip_times) >= self.latch_trips:
                    self.latched = True
            return self.ramp_safe(t)
        return self.v

    def restart_watchdog(self):
        """
        Forget the last command time: the watchdog counts again from the next command.

        For an activation: the silence while the output was inactive (at the safe
        voltage) is no loss of input, and counted it tripped the watchdog at once when
        the timer ran before the first new command (an ERROR and a trip towards the
        latch for nothing, and a resume that waited for fresh input).
        """
        self.t_last_cmd = None

    def start_at(self, v):
        """Take the output to be ``v`` (V, clamped to the limits; a device's read-back)."""
        self.v = min(max(float(v), self.v_min), self.v_max)
        return self.v

    def set_limits(self, new):
        """
        Apply live limit changes, keeping the running state (output, trips, watchdog).

        :param new: ``{name: value}`` of the ``actuator_driver`` parameters (SI):
            ``v_min``, ``v_max``, ``slew_rate_v_per_s``, ``watchdog_timeout_s``,
            ``safe_voltage_v``, ``latch_trips``, ``latch_window_s``,
            ``safe_ramp_rate_v_per_s``; absent names keep their value.
        """
        self.v_min = float(new.get('v_min', self.v_min))
        self.v_max = float(new.get('v_max', self.v_max))
        self.timeout = float(new.get('watchdog_timeout_s', self.timeout))
        self.safe = float(new.get('safe_voltage_v', self.safe))
        self.latch_trips = int(new.get('latch_trips', self.latch_trips))
        self.latch_window_s = float(new.get('latch_window_s', self.latch_window_s))
        for key, attr in (('safe_ramp_rate_v_per_s', 'safe_rate'),
                          ('slew_rate_v_per_s', 'slew')):
            if key in new:
                r = float(new[key])
                setattr(self, attr, r if r > 0 and math.isfinite(r) else math.inf)

    def rearm(self):
        """End a latched safe state and forget the trip history (output unchanged)."""
        self.latched = False
        self.trip_times = []


def check_field_limits(p):
    """
    Return ``None`` or why the drive limits in ``p`` break a field limit (V).

    :param p: mapping with ``v_min``, ``v_max``, ``safe_voltage_v``, ``field_limit_v``,
        ``coercive_field_v`` and ``depoling_fraction`` (V, V, V, V, V, 1).
    """
    fwd = float(p['field_limit_v'])
    rev = -float(p['depoling_fraction']) * float(p['coercive_field_v'])
    for k in ('v_max', 'v_min', 'safe_voltage_v'):
        v = float(p[k])
        if not math.isfinite(v):
            return '%s=%r is not finite' % (k, v)
        if v > fwd:
            return ('%s %g V exceeds the field limit %g V (field_limit_v)' % (k, v, fwd))
        if v < rev:
            return ('%s %g V is below the depoling limit %g V (-depoling_fraction %g * '
                    'coercive_field_v %g V)'
                    % (k, v, rev, float(p['depoling_fraction']), float(p['coercive_field_v'])))
    return None
