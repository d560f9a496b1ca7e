# SPDX-License-Identifier: Apache-2.0
"""
DriverAxes: the per-axis rules of one driver for N axes, held together (pure, no rclpy).

Each axis has its :class:`~fiber_align.control.driver.DriverCore` (clamp, slew, watchdog,
latch, ramp to the safe voltage) and its
:class:`~fiber_align.control.realtime.DriverStep` (which input makes a command). The
driver's policy over them is here, once: the output follows the inputs only while the
driver is active and enabled; a watchdog trip of any axis holds every axis (each ramps
to its own safe voltage until every input is fresh again: a two-axis alignment with one
axis frozen is no alignment); a second publisher on a command or drive topic (another
graph's, :meth:`DriverAxes.intrusion`) holds every axis where it is until it is gone and
the operator re-arms; ``held`` (``drive_held``) is one value for every axis. For
one axis this is the 1-D driver's behaviour unchanged. Lockstep pairs the i-th
feedforward with the i-th feedback of each axis.

The node calls it with the clock readings (monotonic s) and message values (V) and
publishes what it returns: drives ``[(axis, V)]`` and events ``(kind, axis, text)``
(:attr:`DriverAxes.events`: ``trip``, ``latch`` and ``foreign`` are errors, ``back``,
``rearm``, ``gone`` and ``resume`` information). SI units (V, s, V/s).
"""

from fiber_align.config import ConfigError
from fiber_align.control.driver import check_field_limits, DriverCore
from fiber_align.control.realtime import DriverStep

#: Keys each axis has of its own (``<axis>.<key>``; the unnamed axis: ``<key>``).
AXIS_KEYS = ('channel', 'v_min', 'v_max', 'safe_voltage_v')
#: Each axis's inputs, (topic, is the feedforward); the feedback is absent when sensorless.
INPUTS = (('feedforward_voltage', True), ('feedback_voltage', False))
#: DriverCore keys every axis shares (one value, each axis's core has it).
SHARED_KEYS = ('slew_rate_v_per_s', 'watchdog_timeout_s', 'latch_trips', 'latch_window_s',
               'safe_ramp_rate_v_per_s')
#: The field limits of the PZT layers the drive limits are checked against.
LIMIT_KEYS = ('field_limit_v', 'coercive_field_v', 'depoling_fraction')
#: name: (low, high) of the limit parameters (V, V/s, s, 1).
RANGES = {'v_min': (-1000.0, 1000.0), 'v_max': (-1000.0, 1000.0),
          'slew_rate_v_per_s': (-1.0, 1e12), 'watchdog_timeout_s': (0.0, 60.0),
          'safe_voltage_v': (-1000.0, 1000.0), 'latch_trips': (0, 1000),
          'latch_window_s': (0.0, 3600.0), 'safe_ramp_rate_v_per_s': (-1.0, 1e12)}
#: name: description with the unit.
UNITS = {'v_min': 'lowest drive (V)', 'v_max': 'highest drive (V)',
         'slew_rate_v_per_s': 'slew limit (V/s); <= 0: none',
         'watchdog_timeout_s': 'silence before the safe ramp (s); 0: off',
         'safe_voltage_v': 'safe (light-off) drive (V)',
         'latch_trips': 'watchdog trips within latch_window_s that latch the safe '
                        'voltage (0: never)',
         'latch_window_s': 'window of the latch count (s)',
         'safe_ramp_rate_v_per_s': 'rate of every ramp to the safe voltage (V/s); <= 0: '
                                   'the slew limit'}

#: The driver's read-only settings: name -> (description, low, high, choices).
SETTINGS = {
    'backend': ('where the drive goes: topic (drive_voltage, the simulated actuator) or '
                'mdt693b (also a Thorlabs MDT693B channel per axis)', None, None,
                ('topic', 'mdt693b')),
    'axes': ('the axes driven (each with its <axis>.* keys); [""]: one, unprefixed',
             None, None, None),
    'field_limit_v': ('forward field limit of the PZT layers (V)', 0.0, 1000.0, None),
    'coercive_field_v': ('coercive field times layer thickness (V)', 0.0, 10000.0, None),
    'depoling_fraction': ('reverse drive allowed, as a fraction of coercive_field_v (1)',
                          0.0, 1.0, None)}


def axis_name(axis, key):
    """Return the parameter name of ``key`` of ``axis`` (``x.v_max``; unnamed: ``v_max``)."""
    return '%s.%s' % (axis, key) if axis else key


def axis_topic(axis, name):
    """Return topic ``name`` of ``axis`` (``x/drive_voltage``; unnamed: ``drive_voltage``)."""
    return '%s/%s' % (axis, name) if axis else name


def check_axis(p):
    """Return ``None`` or why ``p`` (one axis's limits and the field limits) cannot drive."""
    why = check_field_limits(p)
    if why:
        return why
    try:
        DriverCore.from_params(p)
    except (ConfigError, ValueError) as exc:
        return str(exc)
    return None


class DriverAxes:
    """
    The cores, input rules and hold-together policy of one driver's axes (V, s).

    :param axes: ``{axis: params}`` in axis order, each with the
        :class:`~fiber_align.control.driver.DriverCore` keys (``''``: the one unnamed
        axis of the 1-D driver).
    :param period_s: control period (s): each ramp step and the lockstep time step.
    :param note: called with a line for the log (an input back after a trip).
    """

    def __init__(self, axes, period_s, note=None):
        """Build one core and one input rule per axis; inactive, enabled, at safe."""
        self.period_s = float(period_s)
        self.cores = {a: DriverCore.from_params(p, ramp_period_s=self.period_s)
                      for a, p in axes.items()}
        self.steps = {a: DriverStep(c, self.period_s, note) for a, c in self.cores.items()}
        self.active = False
        self.enabled = True
        self.foreign = None             # the foreign publishers seen last (text), or None
        self.blocked = False            # held for them until gone and re-armed
        self.events = []                # (kind, axis, text) for the node to report
        self.last = {a: None for a in self.cores}       # the drive returned last (V)
        self._queues = {a: ([], []) for a in self.cores}    # lockstep ff, fb
        self._i = {a: 0 for a in self.cores}

    @property
    def held(self):
        """Return True while the output does not follow the inputs (``drive_held``)."""
        return not (self.active and self.enabled) or bool(self.blocked) or self.tripped()

    def tripped(self, but=None):
        """Return True while an axis (other than ``but``) is tripped or latched."""
        return any(c.tripped or c.latched for a, c in self.cores.items() if a != but)

    # -- lifecycle ------------------------------------------------------------------
    def activate(self):
        """Follow the inputs; a latched watchdog is re-armed (a lifecycle cycle)."""
        for a, c in self.cores.items():
            if c.latched:
                c.rearm()
                self.events.append(('rearm', a, 'watchdog latch re-armed by activate'))
            c.restart_watchdog()        # the inactive time is no loss of input
        self.active = True
        self._rearm('a lifecycle deactivate/activate')

    def intrusion(self, text, pending=False):
        """
        Take the newest check of the command and drive topics' publishers.

        A second publisher (``text`` names it) holds every output where it is (the inputs
        are not followed, the watchdog does not run) until it is gone (``text`` None)
        and the operator re-arms (:meth:`enable` true, :meth:`activate`). ``pending``: a
        second one matched but not named yet: held, and let go without a re-arm when
        the names show none foreign (a restarted node's expired writer).
        """
        was, self.foreign = self.foreign, text
        if text and pending:
            self.blocked = self.blocked or 'pending'
        elif not text and self.blocked == 'pending':
            self.blocked = False
            for c in self.cores.values():
                c.restart_watchdog()    # the held time is no loss of input
        elif text and text != was:
            self.blocked = True
            self.events.append(('foreign', '', 'second publisher on a command or drive '
                                'topic: %s; every output held at %s until it is gone and '
                                '~/enable true or a lifecycle deactivate/activate' % (
                                    text, ', '.join('%.4g V' % c.v for c in
                                                    self.cores.values()))))
        elif was and not text and self.blocked:
            self.events.append(('gone', '', 'the foreign publisher is gone; output held '
                                'until ~/enable true or a lifecycle deactivate/activate'))

    def _rearm(self, how):
        if not self.blocked:
            return
        if self.foreign or self.blocked == 'pending':
            self.events.append(('foreign', '', 'not re-armed by %s: still %s' % (
                how, self.foreign)))
            return
        self.blocked = False
        for c in self.cores.values():
            c.restart_watchdog()        # the held time is no loss of input
        self.events.append(('resume', '', 're-armed by %s: following the inputs' % how))

    def deactivate(self, now, lockstep):
        """Follow no more; return the drives: lockstep the safe voltages, else a ramp."""
        self.active = False
        if lockstep:
            return self._out([(a, c.safe) for a, c in self.cores.items()])
        for c in self.cores.values():
            c.start_safe_ramp(now)
        return []

    def at(self, volts):
        """
        Take the outputs to be ``{axis: V}`` (a device's read-back, its safe voltages).

        :returns: ``{axis: V}`` clamped to each axis's limits.
        """
        return {a: self.cores[a].start_at(v) for a, v in volts.items()}

    def at_safe(self):
        """Take every output to be at its safe voltage (the device ramped there)."""
        return self.at({a: c.safe for a, c in self.cores.items()})

    def enable(self, on, now):
        """
        Enable (``on``) or disable the output: disabled, every axis ramps to safe.

        An enable acknowledges the trips so far (and re-arms a latch).

        :returns: the axes whose trip history it cleared.
        """
        if self.enabled and not on:
            for c in self.cores.values():
                c.start_safe_ramp(now)
        self.enabled = bool(on)
        rearmed = [a for a, c in self.cores.items() if on and (c.latched or c.trip_times)]
        for a in rearmed:
            self.cores[a].rearm()
        if on:
            self._rearm('~/enable true')
        return rearmed

    def set_limits(self, axis, new):
        """Apply live limit changes ``{key: value}`` (SI) to ``axis``'s core."""
        self.cores[axis].set_limits(new)

    # -- inputs ---------------------------------------------------------------------
    def feedforward(self, axis, v, now, sensorless=False):
        """Realtime: take the newest feedforward voltage (V) at ``now`` (s); return drives."""
        return self._realtime(axis, self.steps[axis].feedforward(v, now, self.enabled,
                                                                 sensorless), now)

    def feedback(self, axis, v, now):
        """Realtime: take the newest feedback voltage (V) at ``now`` (s); return drives."""
        return self._realtime(axis, self.steps[axis].feedback(v, now, self.enabled), now)

    def input(self, axis, ff, v, now, sensorless=False, lockstep=False):
        """
        Take a feedforward (``ff`` True) or feedback voltage ``v`` (V); return the drives.

        Lockstep: queued and paired in order (:meth:`pair`); realtime at ``now`` (s):
        :meth:`feedforward` or :meth:`feedback`.
        """
        if lockstep:
            return self.pair_ff(axis, v) if ff else self.pair_fb(axis, v)
        return (self.feedforward(axis, v, now, sensorless) if ff else
                self.feedback(axis, v, now))

    def pair_ff(self, axis, v):
        """Lockstep: queue the next feedforward (V); return the drives of new pairs."""
        self._queues[axis][0].append(v)
        return self.pair(axis)

    def pair_fb(self, axis, v):
        """Lockstep: queue the next feedback (V); return the drives of new pairs."""
        self._queues[axis][1].append(v)
        return self.pair(axis)

    def pair(self, axis):
        """
        Lockstep: drive the queued pairs of ``axis`` in order (while active).

        Inactive, the pairs are kept (a plant that started at configure, when the
        drive's publisher appeared, waits for the drive of its first sample).
        """
        ff, fb = self._queues[axis]
        out = []
        while self.active and ff and fb:
            t = self._i[axis] * self.period_s
            self._i[axis] += 1
            out += self._command(axis, ff.pop(0), fb.pop(0), t)
        return out

    def _realtime(self, axis, cmd, now):
        return [] if cmd is None else self._command(axis, cmd[0], cmd[1], now, cmd[2])

    def _command(self, axis, ff, fb, t, t_input=None):
        core = self.cores[axis]
        if not self.active:
            return []       # inactive: the output ramps to, and stays at, the safe voltage
        if not self.enabled:
            return self._out([(axis, core.ramp_safe(t))])
        if self.blocked:        # a foreign publisher: hold the output where it is
            return self._out([(axis, core.v)])
        was = core.tripped
        if len(self.cores) > 1 and self.tripped(but=axis):
            # another axis tripped: this one's input is fresh, but it holds (ramps to safe)
            v = core.hold(t, t_input)
        else:
            v = core.command(ff, fb, t, t_input)
        if was and not core.tripped:
            self.events.append(('back', axis, 'input is back: watchdog cleared after trip %d'
                                % core.watchdog_count))
        return self._out([(axis, v)])

    def tick(self, t, inputs='feedforward_voltage'):
        """
        Run every axis's watchdog at ``t`` (s); return the drives.

        Inactive or disabled: each output ramps to its safe voltage, then nothing more.
        A trip of any axis starts the safe ramp of every axis (``trip`` events; ``latch``
        when it latched).

        :param inputs: the inputs named in a trip's text.
        """
        out = []
        if not (self.active and self.enabled):
            for a, c in self.cores.items():
                if c.v != c.safe or (self.active and c.t_last_out is None):
                    out.append((a, c.ramp_safe(t)))
            return self._out(out)
        if self.blocked:        # held where it is: no input is followed, none is due
            return []
        tripped = []
        for a, c in self.cores.items():
            before, was_at = c.watchdog_count, c.v
            v = c.tick(t)
            if c.watchdog_count > before:
                tripped.append(a)
                self.steps[a].tripped()
            if c.tripped and (v != was_at or self.last[a] != v):
                out.append((a, v))
        for a in tripped:
            self._trip(a, t, inputs, len(tripped))
        if tripped:
            for a, c in self.cores.items():         # the others hold as well
                if a not in tripped and not c.tripped:
                    c.start_safe_ramp(t)
        return self._out(out)

    def _trip(self, axis, t, inputs, n):
        core, step = self.cores[axis], self.steps[axis]
        ages = ', '.join('%s %s' % (k, 'never' if tk is None else '%.3f s old' % (t - tk))
                         for k, tk in (('feedforward', step.t_ff), ('feedback', step.t_fb))
                         if k + '_voltage' in inputs)
        where = 'axis %s: ' % axis if axis else ''
        then = ('every axis ramps to its safe voltage' if len(self.cores) > 1 else
                'ramping to %g V' % core.safe)
        self.events.append(('trip', axis, 'watchdog: %sno fresh %s for %.3g s (%s): %s'
                            % (where, inputs, core.timeout, ages, then)))
        if core.latched:
            self.events.append(('latch', axis, (
                'watchdog latched after %d trips within %g s: output held at %g V until '
                '~/enable true or a lifecycle deactivate/activate'
                % (len(core.trip_times), core.latch_window_s, core.safe))))

    def _out(self, drives):
        for a, v in drives:
            self.last[a] = v
        return drives

    def take_events(self):
        """Return the events since the previous call and forget them."""
        ev, self.events = self.events, []
        return ev

    def values(self, axis):
        """Return the diagnostics values of ``axis`` (V and counts)."""
        c = self.cores[axis]
        return {'drive_v': c.v, 'v_min': c.v_min, 'v_max': c.v_max,
                'saturation_count': c.saturation_count, 'slew_count': c.slew_count,
                'watchdog_count': c.watchdog_count, 'nan_count': c.nan_count,
                'watchdog_latched': c.latched}


def parameter_table(axes, defaults):
    """
    Return the driver's limit parameters for ``axes``: ``[(name, default, text, lo, hi)]``.

    Each axis's own keys (:data:`AXIS_KEYS` but ``channel``, ``<axis>.<key>``; a default
    in ``defaults`` under that name, else the key's), then the shared keys
    (:data:`SHARED_KEYS`).
    """
    out = []
    for a in axes:
        for k in AXIS_KEYS[1:]:
            n = axis_name(a, k)
            out.append((n, defaults.get(n, defaults[k]), '%s, axis %r' % (UNITS[k], a))
                       + RANGES[k])
    return out + [(k, defaults[k], UNITS[k] + ' (each axis)') + RANGES[k]
                  for k in SHARED_KEYS]


def limit_updates(axes, changed, params=None):
    """
    Return ``{axis: {key: value}}`` of a parameter update ``{name: value}`` (SI), and why not.

    A shared key changes every axis; names that are no limit are left out.

    :param params: ``params(axis, new) -> mapping``: an axis's limits with ``new`` applied,
        checked with :func:`check_axis`; ``None``: no check.
    :returns: ``(new, why)``: ``why`` the first axis's refusal, or None.
    """
    new = {}
    for name, v in changed.items():
        axis, _, k = name.rpartition('.')
        if k not in RANGES or axis not in axes and k not in SHARED_KEYS:
            continue
        for a in (axes if k in SHARED_KEYS else [axis]):
            new.setdefault(a, {})[k] = int(v) if k == 'latch_trips' else float(v)
    why = None if params is None else next(filter(None, (
        check_axis(params(a, n)) for a, n in new.items())), None)
    return new, why
