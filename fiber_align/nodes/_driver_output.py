# SPDX-License-Identifier: Apache-2.0
"""
The output backends of ``actuator_driver`` and its parameter tables.

Backend ``topic`` (the simulated actuator) is ``drive_voltage`` alone: nothing here runs
in the 1 kHz loop then. Backend ``mdt693b`` adds :class:`DeviceOutput`: a Thorlabs
MDT693B/MDT694B channel (:class:`fiber_align.hardware.mdt693b.MDT693BOutput`) served by a
thread of its own, so serial I/O never blocks the executor. The driver hands it every
voltage it has already clamped and slew-limited (:meth:`DeviceOutput.submit`, the newest
one wins: the device's own rate, about 100 commands/s, sets the loop rate); the thread
writes it (the backend refuses anything outside ``[v_min, v_max]`` or the device limit
once more) and reads the output back every ``readback_period_s`` (s). A failure of the
device (port gone, write error, no prompt within ``device_timeout_s``) stops the thread
and leaves its one-line reason in :attr:`DeviceOutput.error`, which the node polls
(:class:`DeviceBackend`, a mixin of the node, as :class:`DriverParameters`: the checks
and live updates of the limits). SI units (V, s, V/s).
"""

import math
import threading
import time

from fiber_align.config import ConfigError, load_params
from fiber_align.control.driver import check_field_limits, DriverCore
from fiber_align.hardware import errors as er
from fiber_align.hardware.mdt693b import CHANNELS, MDT693BOutput
from fiber_align.nodes import _common as c

BACKENDS = ('topic', 'mdt693b')
#: Keys of the ``actuator_driver`` section of ``config/hardware.yaml`` the node declares
#: with those defaults (they only matter for the ``mdt693b`` backend).
HARDWARE_FILE = 'hardware.yaml'
DEVICE_KEYS = ('port', 'channel', 'baud', 'device_limit_v', 'device_timeout_s',
               'ramp_rate_v_per_s', 'ramp_step_s', 'readback_period_s')
DEVICE_DOCS = {  # name: (description with unit, low, high) for the read-only parameters
    'port': ('serial device of the MDT693B (a /dev/serial/by-id link survives re-plugging)',
             None, None),
    'channel': ('amplifier channel driving the bimorph', None, None),
    'baud': ('serial rate (baud)', 1200, 4000000),
    'device_limit_v': ('limit switch of the amplifier (V); 0: read it (vlimit?) at '
                       'configure; > 0: must equal the device', 0.0, 1000.0),
    'device_timeout_s': ('no prompt within this (s) is a lost device', 0.01, 10.0),
    'ramp_rate_v_per_s': ('rate of the ramp to the safe voltage on deactivate and '
                          'shutdown (V/s)', 1e-3, 1e6),
    'ramp_step_s': ('time between two commands of that ramp (s)', 1e-3, 1.0),
    'readback_period_s': ('period of the read-back (xvoltage?) published on '
                          'drive_voltage_readback (s)', 0.005, 60.0),
}
CORE_KEYS = ('v_min', 'v_max', 'slew_rate_v_per_s', 'watchdog_timeout_s', 'safe_voltage_v',
             'latch_trips', 'latch_window_s', 'safe_ramp_rate_v_per_s')
LIMIT_KEYS = ('field_limit_v', 'coercive_field_v', 'depoling_fraction')
RANGES = {'v_min': (-1000.0, 1000.0), 'v_max': (-1000.0, 1000.0),
          'slew_rate_v_per_s': (-1.0, 1e12), 'watchdog_timeout_s': (0.0, 60.0),
          'safe_voltage_v': (-1000.0, 1000.0), 'latch_trips': (0, 1000),
          'latch_window_s': (0.0, 3600.0), 'safe_ramp_rate_v_per_s': (-1.0, 1e12)}
UNITS = {'v_min': 'lowest drive (V)', 'v_max': 'highest drive (V)',
         'slew_rate_v_per_s': 'slew limit (V/s); <= 0: none',
         'watchdog_timeout_s': 'silence before the safe ramp (s); 0: off',
         'safe_voltage_v': 'safe (light-off) drive (V)',
         'latch_trips': 'watchdog trips within latch_window_s that latch the safe '
                        'voltage (0: never)',
         'latch_window_s': 'window of the latch count (s)',
         'safe_ramp_rate_v_per_s': 'rate of every ramp to the safe voltage (V/s); <= 0: '
                                   'the slew limit'}
#: Read-only settings of the node: name -> (description, low, high, choices).
SETTINGS = {
    'rate_hz': ('control rate (Hz); the watchdog ticks at it', 1.0, 20000.0, None),
    'sync_mode': ('message pairing', None, None, 'sync'),
    'sensorless': ('no displacement sensor: drive the feedforward alone (no '
                   'feedback_voltage)', None, None, None),
    'backend': ('where the drive goes: topic (drive_voltage, the simulated actuator) or '
                'mdt693b (also a Thorlabs MDT693B channel)', None, None, BACKENDS),
    'diagnostics_period_s': ('/diagnostics period (s)', 0.01, 60.0, None),
    'field_limit_v': ('forward field limit of the PZT layers (V)', 0.0, 1000.0, None),
    'coercive_field_v': ('coercive field times layer thickness (V)', 0.0, 10000.0, None),
    'depoling_fraction': ('reverse drive allowed, as a fraction of coercive_field_v (1)',
                          0.0, 1.0, None),
}


def declare_all(node, d):
    """
    Declare every parameter of the driver on ``node`` (defaults ``d``, then hardware.yaml).

    :param d: the node's defaults (``driver.yaml`` and ``fiber_align.yaml``).
    """
    hw = load_params(HARDWARE_FILE, 'actuator_driver')
    d = dict(d, **{k: hw[k] for k in DEVICE_KEYS})
    for k, (text, lo, hi, choices) in SETTINGS.items():
        c.declare(node, d, k, text, lo, hi, True,
                  choices=c.SYNC_MODES if choices == 'sync' else choices)
    c.declare_priority(node, d)
    for k in CORE_KEYS:
        c.declare(node, d, k, UNITS[k], *RANGES[k])
    for k in DEVICE_KEYS:
        text, lo, hi = DEVICE_DOCS[k]
        c.declare(node, d, k, text, lo, hi, True,
                  choices=CHANNELS if k == 'channel' else None)


def apply_live(core, new):
    """Apply live limit updates ``new`` (``{name: value}``, SI) to a running DriverCore."""
    core.v_min = new.get('v_min', core.v_min)
    core.v_max = new.get('v_max', core.v_max)
    core.timeout = new.get('watchdog_timeout_s', core.timeout)
    core.safe = new.get('safe_voltage_v', core.safe)
    core.latch_trips = new.get('latch_trips', core.latch_trips)
    core.latch_window_s = new.get('latch_window_s', core.latch_window_s)
    for key, attr in (('safe_ramp_rate_v_per_s', 'safe_rate'),
                      ('slew_rate_v_per_s', 'slew')):
        if key in new:
            r = new[key]
            setattr(core, attr, r if r > 0 and math.isfinite(r) else math.inf)


class DeviceOutput:
    """
    One MDT693B channel behind a writer thread (the ``mdt693b`` backend).

    :param p: the driver's parameters (``v_min``, ``v_max``, ``safe_voltage_v`` and
        :data:`DEVICE_KEYS`; SI).
    """

    def __init__(self, p):
        """Build the backend; nothing is opened until :meth:`configure`."""
        self.out = MDT693BOutput(
            p['port'], p['channel'], int(p['baud']), float(p['v_min']), float(p['v_max']),
            float(p['safe_voltage_v']), float(p['ramp_rate_v_per_s']),
            float(p['ramp_step_s']), float(p['device_timeout_s']),
            float(p['device_limit_v']))
        self.readback_period_s = float(p['readback_period_s'])
        self.info = {}
        self.error = None
        self.readback = None            # (V, monotonic s) of the newest read-back
        self.last_refusal = None
        self._pending = None
        self._cv = threading.Condition()
        self._stop = True
        self._thread = None

    # -- lifecycle ------------------------------------------------------------------
    def configure(self):
        """Open, identify, check the limits (raises DeviceError); return the device info."""
        self.error = None
        self.info = self.out.configure()
        return self.info

    def start(self):
        """Start the writer thread (after a successful :meth:`configure`)."""
        if self._thread is not None:
            return
        self._stop = False
        self._pending = None
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
        t.join(timeout=2.0 * self.out.client.timeout_s + 1.0)
        self._thread = None

    def ramp_safe(self):
        """
        Stop the writer, ramp the output to the safe voltage and leave it there.

        Returns None or the one-line reason of a failure (the device is then lost).
        """
        self.stop()
        if self.error or not self.out.connected or self.out.device_limit_v is None:
            return self.error
        try:
            self.out.ramp_to()
        except er.DeviceError as exc:
            self.error = str(exc)
        return self.error

    def close(self):
        """Stop the writer and close the port (the output keeps its voltage)."""
        self.stop()
        self.out.close()

    # -- the loop -------------------------------------------------------------------
    def submit(self, volts):
        """Hand over the newest drive (V, clamped and slew-limited); never blocks long."""
        with self._cv:
            self._pending = volts
            self._cv.notify()

    def _run(self):
        next_rb = time.monotonic()
        while True:
            with self._cv:
                wait = next_rb - time.monotonic()
                if self._pending is None and not self._stop and wait > 0:
                    self._cv.wait(wait)
                if self._stop:
                    return
                v, self._pending = self._pending, None
            try:
                if v is not None:
                    self._write(v)
                if time.monotonic() >= next_rb:
                    next_rb = time.monotonic() + self.readback_period_s
                    self.readback = (self.out.read_back(), time.monotonic())
            except er.DeviceError as exc:
                self.error = str(exc)
                return

    def _write(self, v):
        try:
            self.out.write(v)
        except er.LimitError as exc:    # never reached the device; counted, not fatal
            self.last_refusal = str(exc)

    def values(self):
        """Return the diagnostics values of the device (SI)."""
        rb = self.readback
        return {'device': (self.info.get('ident') or '').splitlines()[0]
                if self.info.get('ident') else '',
                'device_limit_v': self.out.device_limit_v,
                'readback_v': rb[0] if rb else None, 'device_writes': self.out.writes,
                'device_refused': self.out.refused}


class DriverParameters:
    """The limit parameters of ``ActuatorDriverNode``: checks and live updates (mixin)."""

    def _core_params(self, overrides=None):
        p = {k: self.get_parameter(k).value for k in CORE_KEYS + LIMIT_KEYS}
        p.update(overrides or {})
        return p

    def _check_core(self, p):
        """Return ``None`` or the reason why ``p`` is not a valid driver set-up."""
        why = check_field_limits(p)
        if why:
            return why
        try:
            DriverCore.from_params(p)
        except (ConfigError, ValueError) as exc:
            return str(exc)
        return None

    def _on_set(self, params):
        """Accept live updates of the limits when in range and consistent."""
        res = c.check_parameters(params, RANGES)
        if not res.successful:
            return res
        new = {p.name: float(p.value) for p in params if p.name in CORE_KEYS}
        if 'latch_trips' in new:
            new['latch_trips'] = int(new['latch_trips'])
        if new:
            why = self._check_core(self._core_params(new))
            if why:
                res.successful = False
                res.reason = why
                return res
            if self.core is not None:
                apply_live(self.core, new)
        return res


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
        core.v = min(max(float(info['readback_v']), core.v_min), core.v_max)
        out.out.last_written_v = core.v     # a later ramp starts where the output is
        self.out, self.lost, self.n_rb = out, None, 0
        self.pub_rb = c.Pub(self, msg_type, 'drive_voltage_readback', c.CONTROL_QOS,
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
        self.health.status(c.ERROR, text + '; a configure reconnects')
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
            self.health.status(c.ERROR, 'device lost: %s' % why)
            self.get_logger().error('device lost during the ramp: %s' % why)
            return why
        if self.core is not None:
            self.core.v = self.core.safe
        return None

    def _close_device(self):
        """Cleanup / error / shutdown: close the port (after a ramp, if any)."""
        if self.out is not None:
            self.out.close()
            self.out = None
        if self.pub_rb is not None:
            self.pub_rb.destroy(self)
            self.pub_rb = None

    def destroy_node(self):
        """Process exit (SIGINT, no lifecycle shutdown): ramp to the safe voltage, close."""
        if getattr(self, 'out', None) is not None:
            self._ramp_device()
            self._close_device()
        return super().destroy_node()
