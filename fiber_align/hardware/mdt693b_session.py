# SPDX-License-Identifier: Apache-2.0
"""
The device session of a driver node on an MDT693B: open, write, read back, lost, ramp, close.

:class:`DeviceSession` serves the channels of one Thorlabs MDT693B/MDT694B
(:class:`fiber_align.hardware.mdt693b_channels.MDT693BChannels`) from a thread of its
own, the serial link's one owner, so serial I/O never runs on a control thread: a driver
hands it every voltage it has already clamped and slew-limited (:meth:`submit`, the
newest one of each axis wins; nothing waits) and the thread writes them and reads the
outputs back every ``readback_period_s`` (s), one axis in turn. A failure of the device
stops the thread and leaves its one-line reason in :attr:`DeviceSession.error`, which
the driver polls (:meth:`poll`). The lifecycle steps (:meth:`open`, :meth:`ramp_safe`,
:meth:`close`) run in the driver's transitions, never in its control loop. Pure (no
rclpy); SI units (V, s, V/s).
"""

import threading
import time

from fiber_align.control.driver_axes import axis_name, parameter_table
from fiber_align.hardware import errors as er
from fiber_align.hardware.mdt693b import CHANNELS
from fiber_align.hardware.mdt693b_channels import MDT693BChannels

#: s: the longest a combined write waits for the other axes of its period.
COALESCE_S = 2e-3
#: Keys of the device settings (SI), besides each axis's ``channel`` and limits.
DEVICE_KEYS = ('port', 'baud', 'device_limit_v', 'device_timeout_s', 'ramp_rate_v_per_s',
               'ramp_step_s', 'readback_period_s', 'combined_write')
#: name: (description with unit, low, high) of each device setting (read-only).
DEVICE_DOCS = {
    'port': ('serial device of the MDT693B (a /dev/serial/by-id link survives re-plugging)',
             None, None),
    'baud': ('serial rate (baud)', 1200, 4000000),
    'device_limit_v': ('limit switch of the amplifier (V); 0: read it (vlimit?) at '
                       'configure; > 0: must equal the device', 0.0, 1000.0),
    'device_timeout_s': ('no prompt within this (s) is a lost device', 0.01, 10.0),
    'ramp_rate_v_per_s': ('rate of the ramp to the safe voltage on configure, deactivate '
                          'and shutdown (V/s)', 1e-3, 1e6),
    'ramp_step_s': ('time between two commands of that ramp (s)', 1e-3, 1.0),
    'readback_period_s': ('period of the read-back (<ch>voltage?) published on '
                          'drive_voltage_readback (s)', 0.005, 60.0),
    'combined_write': ('send the axes of one period in one xyzvoltage= (the channels no '
                       'axis owns are re-sent their read-back)', None, None),
}


def backend_defaults(backend, hw, port):
    """
    Return the defaults a driver's ``backend`` brings over its own (SI).

    :param hw: the driver's section of ``hardware.yaml`` (the ``mdt693b`` backend's).
    :param port: the device address (``hardware.yaml``'s ``/**``, where a ``-p`` wins).
    :returns: for ``mdt693b`` every key of ``hw`` but ``backend``; else the device keys
        and ``channel`` alone (declared, unused).
    """
    hw = dict(hw, port=port)
    hw.pop('backend', None)
    return hw if backend == 'mdt693b' else {k: hw[k] for k in DEVICE_KEYS + ('channel',)}


def parameter_rows(axes, d):
    """
    Return the driver's per-axis and device parameters as declaration rows.

    A row is ``(name, default, text, lo, hi, read_only, choices)``: each axis's
    ``channel`` (read-only), the limits of
    :func:`~fiber_align.control.driver_axes.parameter_table` (live), the device settings
    :data:`DEVICE_KEYS` (read-only); defaults from ``d`` (an axis's ``<axis>.<key>``,
    else the key's).
    """
    rows = [(axis_name(a, 'channel'), d.get(axis_name(a, 'channel'), d['channel']),
             'amplifier channel of axis %r' % a, None, None, True, CHANNELS) for a in axes]
    rows += [r + (False, None) for r in parameter_table(axes, d)]
    return rows + [(k, d[k]) + DEVICE_DOCS[k] + (True, None) for k in DEVICE_KEYS]


class DeviceSession:
    """
    The channels of one MDT693B behind one writer thread: the serial link's one owner.

    :param p: the device settings (:data:`DEVICE_KEYS`; SI).
    :param axes: ``{axis: {'channel', 'v_min', 'v_max', 'safe_voltage_v'}}`` (V); the
        axis ``''`` of a one-axis driver is labelled by nothing in the refusals.
    """

    def __init__(self, p, axes):
        """Build the session; nothing is opened until :meth:`open`."""
        self.dev = MDT693BChannels(
            p['port'], axes, int(p['baud']), float(p['device_timeout_s']),
            float(p['device_limit_v']), float(p['ramp_rate_v_per_s']),
            float(p['ramp_step_s']), combined=bool(p.get('combined_write', False)))
        self.port = p['port']
        self.axes = tuple(axes)
        self.readback_period_s = float(p['readback_period_s'])
        # all axes of a period together: a combined write waits this long (s) for the
        # axes not yet submitted
        self.coalesce_s = COALESCE_S if self.dev.combined and len(self.axes) > 1 else 0.0
        self.info = {}
        self.error = None
        self.readbacks = {}             # axis -> (V, monotonic s) of its newest read-back
        self._seen = {}                 # axis -> monotonic s of the read-back polled last
        self.last_refusal = None
        self._pending = {}
        self._cv = threading.Condition()
        self._stop = True
        self._thread = None
        self._next_rb = 0.0
        self.writes = 0                 # write transactions (a combined one is one)
        self._rate = (time.monotonic(), 0, 0.0)     # (t, writes then, writes per s)

    # -- lifecycle ------------------------------------------------------------------
    def open(self, driver):
        """
        Open, identify and check the unit, ramp every axis to its safe voltage, start.

        :param driver: the :class:`~fiber_align.control.driver_axes.DriverAxes` of the
            axes: it takes each output read back as its present one (clamped; the ramp
            starts there, no jump), then the safe voltages.
        :returns: one line for the log: the unit, its limit switch, each axis's channel
            and read-back (V).
        :raises DeviceError: the unit cannot be reached, refuses the limits, or is lost
            during the ramp (the port is closed again).
        """
        self.error = None
        self.info = self.dev.configure()
        if not self.dev.combined:
            self.coalesce_s = 0.0
        rb = self.info['readback_v']
        for a, v in driver.at(rb).items():
            self.dev.outputs[a].last_written_v = v
        try:
            self.dev.ramp_to_safe()
        except er.DeviceError as exc:
            self.error = str(exc)
            self.close()
            raise
        driver.at_safe()
        self.start()
        return '%s on %s: limit switch %g V; read back %s; ramped to safe' % (
            self.values()['device'], self.port, self.info['device_limit_v'], ', '.join(
                '%r (channel %s) %g V' % (a, self.dev.outputs[a].channel, rb[a])
                for a in self.axes))

    def start(self):
        """Start the writer thread (after a successful :meth:`open`; read-back only)."""
        if self._thread is not None:
            return
        self._stop = False
        self._pending = {}
        self._thread = threading.Thread(target=self._run, name='mdt693b-writer',
                                        daemon=True)
        self._thread.start()

    def stop(self):
        """Stop the writer thread (it finishes its transaction, bounded by the timeout)."""
        t = self._thread
        if t is None:
            return
        with self._cv:
            self._stop = True
            self._cv.notify()
        t.join(timeout=2.0 * self.dev.client.timeout_s + 1.0)
        self._thread = None

    def ramp_safe(self):
        """
        Stop the writer, ramp every output to its safe voltage and leave it there.

        Returns None or the one-line reason of a failure (the device is then lost).
        """
        self.stop()
        if self.error or not self.dev.connected or self.dev.device_limit_v is None:
            return self.error
        try:
            self.dev.ramp_to_safe()
        except er.DeviceError as exc:
            self.error = str(exc)
        return self.error

    def close(self):
        """Stop the writer and close the port (the outputs keep their voltages)."""
        self.stop()
        self.dev.close()

    # -- the loop -------------------------------------------------------------------
    def submit(self, volts, axis=''):
        """Hand over the newest drive (V, clamped and slew-limited) of ``axis``."""
        with self._cv:
            self._pending[axis] = volts
            self._cv.notify()

    def poll(self):
        """Return ``{axis: V}`` of the read-backs newer than at the previous call."""
        out = {}
        for a, (v, t) in list(self.readbacks.items()):
            if self._seen.get(a) != t:
                self._seen[a] = t
                out[a] = v
        return out

    def _take(self):
        """Wait for the next values (or the read-back time); return them, or None to stop."""
        with self._cv:
            wait = self._next_rb - time.monotonic()
            if not self._pending and not self._stop and wait > 0:
                self._cv.wait(wait)
            if self._pending and self.coalesce_s > 0 and len(self._pending) < len(self.axes):
                self._cv.wait_for(lambda: self._stop or len(self._pending) == len(self.axes),
                                  self.coalesce_s)
            if self._stop:
                return None
            v, self._pending = self._pending, {}
            return v

    def _run(self):
        self._next_rb = time.monotonic()
        rb_axis = 0
        while True:
            v = self._take()
            if v is None:
                return
            try:
                if v:
                    self._write(v)
                if time.monotonic() >= self._next_rb:
                    # one axis a read-back period, in turn: the link's time goes to drives
                    axis = self.axes[rb_axis % len(self.axes)]
                    rb_axis += 1
                    self._next_rb = time.monotonic() + self.readback_period_s / len(self.axes)
                    self.readbacks[axis] = (self.dev.read_back(axis), time.monotonic())
            except er.DeviceError as exc:
                self.error = str(exc)
                return

    def _write(self, values):
        try:
            self.writes += self.dev.write(values)
        except er.LimitError as exc:    # never reached the device; counted, not fatal
            self.last_refusal = str(exc)

    def rate_hz(self):
        """Return the write transactions per second since the previous call (1/s)."""
        t0, n0, r = self._rate
        now, n = time.monotonic(), self.writes
        if now - t0 >= 0.2:
            r = (n - n0) / (now - t0)
            self._rate = (now, n, r)
        return r

    def values(self, axis=None):
        """
        Return the diagnostics values of the device (``axis`` None) or of one ``axis`` (SI).

        The device's: its ``id?`` line, limit switch, write rate and last refusal; an
        axis's: its channel, newest read-back, writes and refusals.
        """
        if axis is not None:
            rb = self.readbacks.get(axis)
            out = self.dev.outputs[axis]
            return {'channel': out.channel, 'readback_v': rb[0] if rb else None,
                    'device_writes': out.writes, 'device_refused': out.refused}
        ident = (self.info.get('ident') or '').strip()
        return {'device': ident.splitlines()[0] if ident else '',
                'device_limit_v': self.dev.device_limit_v, 'port': self.port,
                'command_rate_hz': self.rate_hz(), 'combined_write': self.dev.combined,
                'last_refusal': self.last_refusal or ''}
