# SPDX-License-Identifier: Apache-2.0
"""
DriverSession: one driver's axes and device through its lifecycle (pure, no rclpy).

The steps a driver node takes at each transition and period, once for every backend:
the axes' rules (:class:`~fiber_align.control.driver_axes.DriverAxes`) and the device
(:class:`~fiber_align.hardware.mdt693b_session.DeviceSession` for backend ``mdt693b``,
:class:`NoDevice` for ``topic``): open and ramp to safe at configure, every drive handed
to the device's writer thread (nothing on the control thread waits for the port), the
read-backs, a lost device, the ramp to the safe voltages at deactivate and shutdown, the
close. Every method returns the drives ``[(axis, V)]`` to publish; what the node reports
collects in :attr:`DriverSession.reports`: ``(kind, axis, text)`` with kind ``error``
(a log error, the status ERROR and latched), ``info`` (a log line), ``ok``, ``warn``,
``fail`` (the steady status; axis ``None``: every status). SI units (V, s).
"""

from fiber_align.control.driver_axes import check_axis, DriverAxes
from fiber_align.hardware import errors as er
from fiber_align.hardware.mdt693b_channels import check_channels
from fiber_align.hardware.mdt693b_session import DeviceSession

#: The steady status an event of the axes leaves (``drive_held`` for a foreign publisher).
STEADY = {'back': 'ok', 'foreign': 'fail', 'gone': 'warn', 'resume': 'ok'}
#: What each backend's output is while the driver is unconfigured.
IDLE_OUTPUT = {'topic': '0 V', 'mdt693b': 'untouched'}


def refusal(axes, device, lockstep=False):
    """
    Return None or why a driver cannot be configured (one line).

    :param axes: ``{axis: params}`` (limits, field limits and ``channel``; SI).
    :param device: the device settings, or None (no device: the channels do not matter).
    :param lockstep: the graph pairs by index (a device runs in wall time).
    """
    if device is not None and lockstep:
        return 'backend mdt693b needs sync_mode realtime (the device runs in wall time)'
    why = None if device is None else check_channels(
        {a: p['channel'] for a, p in axes.items()})
    return why or next(filter(None, (check_axis(p) for p in axes.values())), None)


def open_session(axes, period_s, device=None, lockstep=False, sensorless=False, enabled=True,
                 note=None):
    """
    Return ``(session, why)``: a :class:`DriverSession` opened (device ramped to safe), or why not.

    The arguments are :class:`DriverSession`'s; ``why`` is one line (:func:`refusal`, or
    the device's refusal: a DeviceError or a ValueError), the session then closed.
    """
    why, session = refusal(axes, device, lockstep), None
    try:
        if not why:
            session = DriverSession(axes, period_s, device, lockstep, sensorless, enabled,
                                    note)
            session.open()
    except (er.DeviceError, ValueError) as exc:
        why = str(exc)
    return (session if not why else None), why


class DriverSession:
    """
    The lifecycle of one driver: its axes, its device, a loss (V, s).

    :param axes: ``{axis: params}`` (the DriverCore keys and ``channel``).
    :param period_s: control period (s).
    :param device: the device settings (``mdt693b``), or ``None`` (``topic``).
    :param lockstep: pair the inputs by index (no device then).
    :param sensorless: no feedback: every feedforward is a command.
    :param enabled: the output enabled (``~/enable``).
    :param note: called with a line for the log (an input back after a trip).
    """

    def __init__(self, axes, period_s, device=None, lockstep=False, sensorless=False,
                 enabled=True, note=None):
        """Build the axes and the (unopened) device."""
        self.driver = DriverAxes(axes, period_s, note)
        self.driver.enabled = enabled
        self.dev = DeviceSession(device, axes) if device is not None else NoDevice()
        self.device = device is not None
        self.lockstep, self.sensorless = lockstep, sensorless
        self.inputs = 'feedforward_voltage' if sensorless else \
            'feedback_voltage and feedforward_voltage'
        self.lost = None
        self.reports = []

    def open(self):
        """Open the device and ramp it to the safe voltages (raises DeviceError, ValueError)."""
        line = self.dev.open(self.driver)
        self.reports += [('info', None, line)] if line else []
        self.reports.append(('ok', None, 'configured (inactive): output %s' % ', '.join(
            '%g V' % c.v for c in self.driver.cores.values())))

    def activate(self):
        """Follow the inputs; return the lockstep pairs that came while inactive."""
        self.driver.activate()
        self._events()
        self.reports += [('ok', None, 'active'), ('info', None, 'active: %s pairing, %s' % (
            'lockstep' if self.lockstep else 'latest', ', '.join('%r %g..%g V' % (
                a, c.v_min, c.v_max) for a, c in self.driver.cores.items())))]
        return [d for a in self.driver.cores for d in self.driver.pair(a)] \
            if self.lockstep else []

    def deactivate(self, now):
        """Follow no more; return the drives (lockstep: the safe voltages; device: at them)."""
        out = self._submit(self.driver.deactivate(now, self.lockstep))
        if self.ramp():
            return out
        if self.device:                 # the device is at them already
            out += list(self.driver.at_safe().items())
        self.dev.start()                # read-back only (nothing pending)
        self.reports.append(('ok', None, 'inactive: output at the safe voltage'))
        return out

    def ramp(self):
        """Ramp the device to the safe voltages; return the loss (one line) or None."""
        if self.lost is None:
            self.lost = self.dev.ramp_safe()
            if self.lost:
                self.reports.append(('error', '', 'device lost during the ramp: %s'
                                     % self.lost))
            elif self.device:       # a device ramps itself; a topic output ramps by tick
                self.driver.at_safe()
        return self.lost

    def close(self):
        """Close the device (its outputs keep their voltages: ramp first)."""
        self.dev.close()

    def input(self, axis, ff, v, now):
        """Take a feedforward (``ff``) or feedback voltage ``v`` (V) at ``now`` (s)."""
        if self.lost is not None:
            return []
        out = self._submit(self.driver.input(axis, ff, v, now, self.sensorless,
                                             self.lockstep))
        if self.driver.events:
            self._events()
        return out

    def enable(self, on, now):
        """Enable (``on``) or disable the output; an enable re-arms the trips so far."""
        for a in self.driver.enable(on, now):
            self.reports.append(('info', a, 'watchdog re-armed by ~/enable (trip history '
                                 'cleared)'))
            if not self.driver.cores[a].tripped:
                self.reports.append(('ok', a, 'active' if self.driver.active else 'inactive'))
        self._events()                  # a hold for a foreign publisher re-armed, or not

    def intrusion(self, text, pending=False):
        """Take the newest check of the topics' publishers (:meth:`DriverAxes.intrusion`)."""
        self.driver.intrusion(text, pending)
        self._events()

    def tick(self, now):
        """
        One period: the device's loss and read-backs, then every axis's watchdog.

        :returns: ``(drives, read-backs {axis: V}, loss)``: the loss (one line) the first
            time the device is found lost, else None.
        """
        if self.dev.error and self.lost is None:
            self.lost = self.dev.error
            text = 'device lost: %s' % self.lost
            self.reports += [('error', '', text), ('fail', None, text),
                             ('fail', '', text + '; a configure reconnects')]
            return [], {}, self.lost
        out = self._submit(self.driver.tick(now, self.inputs))
        if self.driver.events:
            self._events()
        return out, self.dev.poll(), None

    def _submit(self, drives):
        for a, v in drives:
            self.dev.submit(float(v), a)
        return drives

    def _events(self):
        for kind, a, text in self.driver.take_events():
            error = kind in ('trip', 'latch', 'foreign')
            self.reports.append(('error' if error else 'info', a, text))
            if kind in STEADY:      # the foreign publishers' state is every axis's
                self.reports.append((STEADY[kind], None if kind != 'back' else a,
                                     text if kind != 'back' else 'active'))

    @property
    def held(self):
        """Return True while the output does not follow the inputs (or the device is lost)."""
        return self.lost is not None or self.driver.held

    def take_reports(self):
        """Return the reports since the previous call and forget them."""
        out, self.reports = self.reports, []
        return out

    def values(self, axis=None):
        """Return the diagnostics values of the device (``axis`` None) or of ``axis``."""
        if axis is None:
            return dict(self.dev.values(), active=self.driver.active,
                        enabled=self.driver.enabled, errors=self.lost or '',
                        foreign_publishers=self.driver.foreign or '')
        return dict(self.driver.values(axis), **self.dev.values(axis))


class NoDevice:
    """
    Backend ``topic``: no device, the drive is the topic alone (a session that does nothing).

    The interface of :class:`DeviceSession`, so a driver treats both backends alike.
    """

    error = None
    port = ''

    def open(self, driver):
        """Open nothing; return None (no line for the log)."""
        return None

    def start(self):
        """Start nothing."""

    def submit(self, volts, axis=''):
        """Write nothing (V)."""

    def poll(self):
        """Return no read-back."""
        return {}

    def ramp_safe(self):
        """Ramp nothing; return None (nothing lost)."""
        return None

    def close(self):
        """Close nothing."""

    def values(self, axis=None):
        """Return no diagnostics values."""
        return {}
