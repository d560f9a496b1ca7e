# SPDX-License-Identifier: Apache-2.0
"""
The MDT693B output of ``actuator_driver`` (one axis) and ``mdt693b_driver`` (several).

Backend ``topic`` (the simulated actuator) is ``drive_voltage`` alone: nothing here runs
in the 1 kHz loop then. Backend ``mdt693b`` adds :class:`DeviceOutput`: the channels of a
Thorlabs MDT693B/MDT694B (:class:`fiber_align.hardware.mdt693b.MDT693BChannels`) served
by a thread of its own, so serial I/O never blocks the executor. A driver hands it every
voltage it has already clamped and slew-limited (:meth:`DeviceOutput.submit`, the newest
one of each axis wins); the thread writes them and reads the outputs back every
``readback_period_s`` (s). A failure of the device stops the thread and leaves its
one-line reason in :attr:`DeviceOutput.error`, which the node polls
(:class:`DeviceBackend`, a mixin of ``actuator_driver``). SI units (V, s, V/s).
"""

import threading
import time

from fiber_align.hardware import errors as er
from fiber_align.hardware.mdt693b import MDT693BChannels
from fiber_align.nodes._driver_params import DEVICE_KEYS
from fiber_align.nodes.ros.bus import Pub
from fiber_align.nodes.ros.diagnostics import ERROR
from fiber_align.nodes.ros.qos import sample_pub_qos

#: s: the longest a combined write waits for the other axes of its period.
COALESCE_S = 2e-3


class DeviceOutput:
    """
    The channels of one MDT693B behind one writer thread: the serial link's one owner.

    ``actuator_driver`` drives one axis (``''``) on ``p['channel']``; ``mdt693b_driver``
    drives several (``axes``), each submitted on its own and written by this thread
    (with ``combined_write``, the axes of one period in one ``xyzvoltage=``).

    :param p: the device settings (:data:`DEVICE_KEYS` but ``channel``; SI) and, for
        one axis, ``channel``, ``v_min``, ``v_max``, ``safe_voltage_v``.
    :param axes: ``{axis: {'channel', 'v_min', 'v_max', 'safe_voltage_v'}}``; ``None``:
        the one axis ``''`` of ``p``.
    """

    def __init__(self, p, axes=None):
        """Build the backend; nothing is opened until :meth:`configure`."""
        if axes is None:
            axes = {'': {k: p[k] for k in ('channel', 'v_min', 'v_max', 'safe_voltage_v')}}
        self.dev = MDT693BChannels(
            p['port'], axes, int(p['baud']), float(p['device_timeout_s']),
            float(p['device_limit_v']), float(p['ramp_rate_v_per_s']),
            float(p['ramp_step_s']), combined=bool(p.get('combined_write', False)))
        self.axes = tuple(axes)
        #: the one axis's output (``actuator_driver``), else None
        self.out = self.dev.outputs[''] if self.axes == ('',) else None
        self.readback_period_s = float(p['readback_period_s'])
        # all axes of a period together: a combined write waits this long (s) for the
        # axes not yet submitted
        self.coalesce_s = COALESCE_S if self.dev.combined and len(self.axes) > 1 else 0.0
        self.info = {}
        self.error = None
        self.readbacks = {}             # axis -> (V, monotonic s) of its newest read-back
        self.last_refusal = None
        self._pending = {}
        self._cv = threading.Condition()
        self._stop = True
        self._thread = None
        self.t_start = None
        self.writes = 0                 # write transactions (a combined one is one)
        self._rate = (time.monotonic(), 0, 0.0)     # (t, writes then, writes per s)

    @property
    def readback(self):
        """Return ``(V, monotonic s)`` of the one axis's newest read-back (or None)."""
        return self.readbacks.get(self.axes[0])

    # -- lifecycle ------------------------------------------------------------------
    def configure(self):
        """Open, identify, check the limits (raises DeviceError); return the device info."""
        self.error = None
        self.info = self.dev.configure()
        if not self.dev.combined:
            self.coalesce_s = 0.0
        if self.out is not None:
            return dict(self.info, readback_v=self.info['readback_v'][''])
        return self.info

    def start(self):
        """Start the writer thread (after a successful :meth:`configure`)."""
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
        """Return the diagnostics values of the device, or of one ``axis`` (SI)."""
        if axis is not None or self.out is not None:
            a = self.axes[0] if axis is None else axis
            rb = self.readbacks.get(a)
            out = self.dev.outputs[a]
            v = {'readback_v': rb[0] if rb else None, 'device_writes': out.writes,
                 'device_refused': out.refused}
            if axis is not None:
                return dict(v, channel=out.channel)
        else:
            v = {}
        ident = self.info.get('ident') or ''
        return dict(v, device=ident.strip().splitlines()[0] if ident.strip() else '',
                    device_limit_v=self.dev.device_limit_v)


class DeviceBackend:
    """
    The ``mdt693b`` steps of ``ActuatorDriverNode``'s lifecycle (a mixin of the node).

    Uses the node's ``core``, ``health``, ``bus``, ``lockstep``, ``active`` and
    ``_set_held``; keeps ``out`` (:class:`DeviceOutput`), ``pub_rb`` (the read-back
    publisher) and ``lost`` (``None`` or the one-line reason the device was lost).
    """

    def _open_device(self, msg_type):
        """Configure: open, identify and check the device; return ``None`` or why not."""
        if self.backend != 'mdt693b':
            return None
        if self.lockstep:
            return 'backend mdt693b needs sync_mode realtime (the device runs in wall time)'
        p = {k: self.get_parameter(k).value
             for k in DEVICE_KEYS + ('v_min', 'v_max', 'safe_voltage_v')}
        try:
            out = DeviceOutput(p)
            info = out.configure()
        except (er.DeviceError, ValueError) as exc:
            return str(exc)
        core = self.core
        # a later ramp starts where the output is
        out.out.last_written_v = core.start_at(info['readback_v'])
        self.out, self.lost, self.n_rb = out, None, 0
        self.pub_rb = Pub(self, msg_type, 'drive_voltage_readback', sample_pub_qos(self.lockstep),
                          self.bus)
        out.start()
        self.get_logger().info('%s on %s channel %s: limit switch %g V, output %g V' % (
            out.values()['device'], p['port'], p['channel'], info['device_limit_v'],
            info['readback_v']))
        return None

    def _poll_device(self, msg_type):
        """Watchdog tick: publish a new read-back (V); a lost device ends in ERROR."""
        out = self.out
        if out.error and self.lost is None:
            self._device_lost(out.error)
            return
        rb = out.readback
        if rb is not None and rb[1] != self._rb_t and self.pub_rb is not None:
            self._rb_t = rb[1]
            self.pub_rb.publish(msg_type(data=float(rb[0])))
            self.n_rb += 1

    def _device_lost(self, reason):
        """Report the loss at once (log, ERROR on /diagnostics) and go to ERROR."""
        self.lost = reason
        text = 'device lost: %s' % reason
        self.get_logger().error(text)
        self.health.status(ERROR, text + '; a configure reconnects')
        self.health.error(text)
        self._set_held(True, 'device lost')
        # the transition callback returns ERROR (self.lost): on_error closes the port
        if self.active:
            self.trigger_deactivate()
        else:
            self.trigger_cleanup()

    def _ramp_device(self):
        """Deactivate / shutdown: ramp the output to the safe voltage; return the loss."""
        out = self.out
        if out is None or self.lost is not None:
            return self.lost
        why = out.ramp_safe()
        if why:
            self.lost = why
            self.health.status(ERROR, 'device lost: %s' % why)
            self.get_logger().error('device lost during the ramp: %s' % why)
            return why
        if self.core is not None:
            self.core.start_at(self.core.safe)
        return None

    def _close_device(self):
        """Cleanup / error / shutdown: close the port (after a ramp, if any)."""
        if self.out is not None:
            self.out.close()
            self.out = None
        if self.pub_rb is not None:
            self.pub_rb.destroy(self)
            self.pub_rb = None

    def close(self):
        """Process exit (SIGINT, no lifecycle shutdown): ramp to the safe voltage, close."""
        if getattr(self, 'out', None) is not None:
            self._ramp_device()
            self._close_device()

    def destroy_node(self):
        """Ramp and close the device (:meth:`close`), then destroy the node."""
        self.close()
        return super().destroy_node()
