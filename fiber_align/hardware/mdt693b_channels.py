# SPDX-License-Identifier: Apache-2.0
"""
The outputs of an MDT693B / MDT694B that a driver owns (the client: :mod:`.mdt693b`).

:class:`MDT693BOutput` is one channel (configure / write / read_back / ramp_to / close),
refusing anything outside its limits (defence in depth behind the driver's own clamp);
:class:`MDT693BChannels` is several channels of one unit on its one serial link (one
``<ch>voltage=`` each, or one ``xyzvoltage=``). All values SI: V, s, V/s.
"""

import math
import time

from fiber_align.hardware import errors as er
from fiber_align.hardware.mdt693b import channel_name, CHANNELS, DEVICE, MDT693B


def check_channels(channels):
    """
    Return None or why an axis -> channel mapping cannot drive one unit (one line).

    :param channels: ``{axis: channel}`` (channel ``x``, ``y`` or ``z``), in axis order.
    """
    if not channels:
        return 'no axis to drive'
    seen = {}
    for axis, ch in channels.items():
        if ch not in CHANNELS:
            return 'axis %s: channel %r is not one of x, y, z' % (axis, ch)
        if ch in seen:
            return 'channel %s is named twice (axes %s and %s)' % (ch, seen[ch], axis)
        seen[ch] = axis
    return None


class MDT693BOutput:
    """
    The amplifier output a lifecycle driver owns: one channel of an MDT693B/MDT694B.

    Defence in depth: :meth:`write` takes only values the driver has already clamped
    and slew-limited; anything non-finite, outside ``[v_min, v_max]`` or above the
    device's limit switch is refused with :class:`~fiber_align.hardware.errors.LimitError`
    and nothing is sent.

    :param port: serial device path.
    :param channel: ``x``, ``y`` or ``z``.
    :param baud: baud rate.
    :param v_min: lowest voltage the driver may command (V); the device cannot go below 0.
    :param v_max: highest voltage the driver may command (V); refused at configure if
        above the device limit switch (``vlimit?``).
    :param safe_voltage_v: the light-off voltage ramped to on deactivate/shutdown (V).
    :param ramp_rate_v_per_s: rate of :meth:`ramp_to` (V/s).
    :param ramp_step_s: time between two ramp commands (s).
    :param timeout_s: reply timeout of every transaction (s).
    :param device_limit_v: ``0`` = read the limit from the device at configure; a
        value > 0 must equal what the device reports (a check of the wiring).
    :param client: an :class:`MDT693B` shared with the other channels of the unit
        (:class:`MDT693BChannels`); ``None``: a client of its own on ``port``.
    :param label: what the refusals name (``axis y``); ``''``: nothing.
    """

    def __init__(self, port, channel='x', baud=115200, v_min=0.0, v_max=100.0,
                 safe_voltage_v=0.0, ramp_rate_v_per_s=500.0, ramp_step_s=0.01,
                 timeout_s=0.5, device_limit_v=0.0, client=None, label=''):
        """Check the settings; nothing is opened until :meth:`configure`."""
        self.channel = channel_name(channel)
        if not (math.isfinite(v_min) and math.isfinite(v_max) and v_max > v_min):
            raise ValueError('need finite v_min < v_max, got %r, %r' % (v_min, v_max))
        if not v_min <= safe_voltage_v <= v_max:
            raise ValueError('safe_voltage_v %g V outside [%g, %g] V'
                             % (safe_voltage_v, v_min, v_max))
        if not ramp_rate_v_per_s > 0 or not ramp_step_s > 0:
            raise ValueError('ramp_rate_v_per_s and ramp_step_s must be > 0')
        self.client = client if client is not None else MDT693B(port, baud, timeout_s)
        self.label = '%s: ' % label if label else ''
        self.v_min = float(v_min)
        self.v_max = float(v_max)
        self.safe_voltage_v = float(safe_voltage_v)
        self.ramp_rate_v_per_s = float(ramp_rate_v_per_s)
        self.ramp_step_s = float(ramp_step_s)
        self.expected_limit_v = float(device_limit_v)
        self.device_limit_v = None
        self.last_written_v = None
        self.writes = 0
        self.refused = 0
        self.error = None

    @classmethod
    def from_params(cls, p):
        """Build from a mapping with the keys of ``config/hardware.yaml`` (its driver keys)."""
        return cls(p.get('port', '/dev/ttyUSB0'), p.get('channel', 'x'),
                   int(p.get('baud', 115200)), float(p.get('v_min', 0.0)),
                   float(p.get('v_max', 100.0)), float(p.get('safe_voltage_v', 0.0)),
                   float(p.get('ramp_rate_v_per_s', 500.0)),
                   float(p.get('ramp_step_s', 0.01)),
                   float(p.get('device_timeout_s', 0.5)),
                   float(p.get('device_limit_v', 0.0)))

    @property
    def connected(self):
        """Return True while the port is open."""
        return self.client.is_open

    def _guard(self, fn, *args):
        try:
            return fn(*args)
        except er.DeviceError as exc:
            self.error = str(exc)
            if exc.reason in (er.PORT_GONE, er.WRITE_ERROR, er.NO_PROMPT):
                self.client.close()
            raise

    def configure(self):
        """
        Open and identify the device, read its limit switch; refuse an unsafe setup.

        Returns a dict (``ident``, ``device_limit_v``, ``readback_v``). Raises
        :class:`LimitError` (port closed again) when ``v_max`` exceeds the device limit or
        ``v_min`` is below 0 V, :class:`DeviceError` when the device cannot be reached.
        """
        self.error = None
        self._guard(self.client.open)
        try:
            ident = self._guard(self.client.identify)
            limit = self._guard(self.client.voltage_limit)
            self.check_device(ident, limit)
            readback = self._guard(self.client.get_voltage, self.channel)
        except er.DeviceError as exc:
            self.error = str(exc)
            self.client.close()
            raise
        self.last_written_v = None
        return dict(ident=ident, device_limit_v=limit, readback_v=readback)

    def check_device(self, ident, limit):
        """
        Refuse (:class:`LimitError`) a channel the model lacks or limits it cannot take.

        :param ident: the device's ``id?`` text.
        :param limit: its limit switch setting (V).
        """
        if self.channel not in self.client.channels:
            raise er.LimitError(DEVICE, '%schannel %s does not exist on %s' % (
                self.label, self.channel, ident.strip().splitlines()[0] if ident.strip()
                else '?'))
        if self.expected_limit_v > 0 and abs(limit - self.expected_limit_v) > 0.5:
            raise er.LimitError(DEVICE, 'device limit switch is at %g V, configured '
                                'device_limit_v is %g V' % (limit, self.expected_limit_v))
        if self.v_max > limit:
            raise er.LimitError(DEVICE, '%sv_max %g V exceeds the device limit switch '
                                'setting %g V' % (self.label, self.v_max, limit))
        if self.v_min < 0.0:
            raise er.LimitError(DEVICE, '%sv_min %g V is below 0 V, which the MDT693B '
                                'cannot output' % (self.label, self.v_min))
        self.device_limit_v = limit

    def check(self, volts):
        """Return ``volts`` as float if it may be sent, else raise :class:`LimitError`."""
        v = float(volts)
        if not math.isfinite(v):
            raise er.LimitError(DEVICE, '%srefused non-finite voltage %r' % (self.label, v))
        hi = self.v_max
        if self.device_limit_v is not None:
            hi = min(hi, self.device_limit_v)
        if not self.v_min <= v <= hi:
            raise er.LimitError(DEVICE, '%srefused %.6g V outside [%g, %g] V'
                                % (self.label, v, self.v_min, hi))
        return v

    def write(self, volts):
        """Send an already clamped voltage (V) to the channel; refuse anything else."""
        try:
            v = self.check(volts)
        except er.LimitError:
            self.refused += 1
            raise
        if self.device_limit_v is None:
            raise er.DeviceError(DEVICE, er.NOT_CONNECTED, 'write before configure')
        self._guard(self.client.set_voltage, self.channel, v)
        self.last_written_v = v
        self.writes += 1
        return v

    def read_back(self):
        """Return the channel's output voltage as the device reports it (V)."""
        return self._guard(self.client.get_voltage, self.channel)

    def ramp_to(self, target_v=None, sleep=time.sleep):
        """
        Ramp from the last written voltage to ``target_v`` (default: the safe voltage).

        Steps of ``ramp_rate_v_per_s * ramp_step_s`` every ``ramp_step_s``; returns the
        number of commands sent. Starts from the read-back when nothing was written yet.
        """
        target = self.check(self.safe_voltage_v if target_v is None else target_v)
        v = self.last_written_v
        if v is None:
            v = min(max(self.read_back(), self.v_min), self.v_max)
        step = self.ramp_rate_v_per_s * self.ramp_step_s
        n = 0
        while True:
            v = min(v + step, target) if target > v else max(v - step, target)
            self.write(v)
            n += 1
            if v == target:
                return n
            sleep(self.ramp_step_s)

    def close(self):
        """Close the port (the output keeps its last voltage; ramp first)."""
        self.client.close()
        self.device_limit_v = None


class MDT693BChannels:
    """
    Several channels of one MDT693B on its one serial link: the link's one owner.

    Each axis is an :class:`MDT693BOutput` (its channel, limits and safe voltage, its
    refusals) on one shared :class:`MDT693B` client. :meth:`write` sends the values of
    several axes in one period: one ``<ch>voltage=`` each, or with ``combined`` one
    ``xyzvoltage=`` (the channels no axis owns are sent the output read back at
    configure, so they stay where they were to the display's 0.1 V).

    :param port: serial device path.
    :param axes: ``{axis: {'channel', 'v_min', 'v_max', 'safe_voltage_v'}}`` (V).
    :param baud: baud rate.
    :param timeout_s: reply timeout (s).
    :param device_limit_v: as :class:`MDT693BOutput`.
    :param ramp_rate_v_per_s: rate of :meth:`ramp_to_safe` (V/s).
    :param ramp_step_s: time between two of its steps (s).
    :param combined: send several channels in one ``xyzvoltage=`` (MDT693B only; a
        firmware that does not know it is found at configure and then not used).
    :raises ValueError: no axis, or a channel named by two axes.
    """

    def __init__(self, port, axes, baud=115200, timeout_s=0.5, device_limit_v=0.0,
                 ramp_rate_v_per_s=500.0, ramp_step_s=0.01, combined=False):
        """Check the axes; nothing is opened until :meth:`configure`."""
        why = check_channels({axis: a['channel'] for axis, a in axes.items()})
        if why:
            raise ValueError(why)
        self.client = MDT693B(port, baud, timeout_s)
        self.outputs = {axis: MDT693BOutput(
            port, a['channel'], baud, float(a['v_min']), float(a['v_max']),
            float(a['safe_voltage_v']), ramp_rate_v_per_s, ramp_step_s, timeout_s,
            device_limit_v, client=self.client, label='axis %s' % axis if axis else '')
            for axis, a in axes.items()}
        self.combined = bool(combined)
        self.hold_v = {}                # channel -> V sent for channels no axis owns
        self.ident = ''
        self.device_limit_v = None
        self.commands = 0               # voltage commands sent (a combined one is one)
        self.error = None
        self.combined_refused = None    # why the firmware refused xyzvoltage=, if it did

    @property
    def connected(self):
        """Return True while the port is open."""
        return self.client.is_open

    def configure(self):
        """
        Open and identify the unit once; check every axis; read every output back.

        Returns ``dict(ident, device_limit_v, readback_v={axis: V})``. Raises
        :class:`LimitError` (port closed again) or :class:`DeviceError`.
        """
        self.error = None
        first = next(iter(self.outputs.values()))
        try:
            first._guard(self.client.open)
            ident = first._guard(self.client.identify)
            limit = first._guard(self.client.voltage_limit)
            for out in self.outputs.values():
                out.error = None
                out.check_device(ident, limit)
            readback = {axis: out._guard(self.client.get_voltage, out.channel)
                        for axis, out in self.outputs.items()}
            owned = {o.channel for o in self.outputs.values()}
            self.hold_v = {}
            self.combined_refused = None
            if self.combined and len(self.client.channels) == 3:
                self.hold_v = {ch: first._guard(self.client.get_voltage, ch)
                               for ch in CHANNELS if ch not in owned}
                self._probe_combined(readback)
        except er.DeviceError as exc:
            self.error = str(exc)
            self.close()
            raise
        for out in self.outputs.values():
            out.last_written_v = None
        self.ident, self.device_limit_v = ident, limit
        return dict(ident=ident, device_limit_v=limit, readback_v=readback)

    def _probe_combined(self, readback):
        """
        Check that the firmware knows ``xyzvoltage=``: re-send every output's read-back.

        Older firmware answers ``CMD_NOT_DEFINED`` (``mdt69x`` notes the command needs
        firmware version > 2); then every write is one command a channel.
        """
        by_ch = dict(self.hold_v)
        for axis, out in self.outputs.items():
            by_ch[out.channel] = min(max(readback[axis], out.v_min), out.v_max)
        try:
            self.client.set_xyz(*(by_ch[c] for c in CHANNELS))
        except er.DeviceError as exc:
            if exc.reason != er.CMD_NOT_DEFINED:
                raise
            self.combined = False
            self.combined_refused = str(exc)

    def write(self, values):
        """
        Send ``{axis: V}`` (already clamped by the caller; each checked again).

        A refused value (:class:`LimitError`) is not sent, the others are; the first
        refusal is raised after the rest went out. Returns the number of commands sent.
        """
        ok, refused = {}, None
        for axis, v in values.items():
            out = self.outputs[axis]
            try:
                ok[axis] = out.check(v)
            except er.LimitError as exc:
                out.refused += 1
                refused = refused or exc
        if ok and self.device_limit_v is None:
            raise er.DeviceError(DEVICE, er.NOT_CONNECTED, 'write before configure')
        n = 0
        if self.combined and len(ok) > 1 and len(self.client.channels) == 3:
            by_ch = dict(self.hold_v)
            for axis, v in ok.items():
                by_ch[self.outputs[axis].channel] = v
            for out in self.outputs.values():       # an axis not in this period: kept
                if out.channel not in by_ch:
                    by_ch[out.channel] = (out.last_written_v if out.last_written_v
                                          is not None else out.safe_voltage_v)
            first = next(iter(self.outputs.values()))
            first._guard(self.client.set_xyz, *(by_ch[c] for c in CHANNELS))
            for axis, v in ok.items():
                self.outputs[axis].last_written_v = v
                self.outputs[axis].writes += 1
            n = 1
        else:
            for axis, v in ok.items():
                self.outputs[axis].write(v)
                n += 1
        self.commands += n
        if refused is not None:
            raise refused
        return n

    def read_back(self, axis):
        """Return the output voltage (V) of ``axis`` as the device reports it."""
        return self.outputs[axis].read_back()

    def ramp_to_safe(self, sleep=time.sleep):
        """
        Ramp every axis to its safe voltage together, in the steps of each output.

        Returns the number of ramp periods; raises DeviceError when the link fails.
        """
        pos = {}
        for axis, out in self.outputs.items():
            v = out.last_written_v
            if v is None:
                v = min(max(out.read_back(), out.v_min), out.v_max)
            pos[axis] = v
        n = 0
        while True:
            step = {}
            for axis, out in self.outputs.items():
                target, v = out.safe_voltage_v, pos[axis]
                dv = out.ramp_rate_v_per_s * out.ramp_step_s
                nv = min(v + dv, target) if target > v else max(v - dv, target)
                if nv != v or out.last_written_v != target:
                    step[axis] = nv
                pos[axis] = nv
            if not step:
                return n
            self.write(step)
            n += 1
            if all(pos[a] == o.safe_voltage_v for a, o in self.outputs.items()):
                return n
            sleep(min(o.ramp_step_s for o in self.outputs.values()))

    def close(self):
        """Close the port (the outputs keep their voltages; ramp first)."""
        self.client.close()
        self.device_limit_v = None
        for out in self.outputs.values():
            out.device_limit_v = None
