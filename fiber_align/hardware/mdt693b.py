# SPDX-License-Identifier: Apache-2.0
r"""
Thorlabs MDT693B / MDT694B piezo controller over its USB virtual serial port (pyserial).

Protocol as issue 12 states it, checked against what public sources show of real units
(session captures and the PyPI client ``mdt69x``, which was written against real units;
the Thorlabs manual itself was not at hand, see docs/hardware.md): 115200 baud, 8N1, no
flow control; a command is ASCII terminated by a carriage return (CR, ``\r``); line
feeds are ignored. The device answers every command with its prompt: ``>`` in the
present command set, ``*`` in the MDT693A compatibility command set (``cm=1``; ``XV``,
``XR``, ``XH``, ``XL``, ``I``, ``%``, ...). A query answers ``[ value]`` then CR before
the prompt (``xvoltage?`` -> ``[  24.8]\r>``, ``vlimit?`` -> ``[ 100]\r>``); an unknown
command answers ``CMD_NOT_DEFINED`` then the prompt. With the echo on (``echo=1``) the
device first echoes the characters it receives. ``xvoltage?`` reads back the *output*
voltage to 0.1 V, not the last set value (a capture shows ``xvoltage=24.680`` reading
``24.8``). ``vlimit?`` answers the rear-panel output limit switch: 75, 100 or 150 V.

:class:`MDT693B` is the client (one transaction at a time, explicit timeouts, typed
:class:`~fiber_align.hardware.errors.DeviceError`). The outputs a driver owns (one
channel, several channels on one link) are :mod:`fiber_align.hardware.mdt693b_channels`;
the writer thread of a driver node's device session
:mod:`fiber_align.hardware.mdt693b_session`. All values SI: V, s, V/s.
"""

import re
import time

try:                                   # tcdrain / tcgetattr on a vanished port raise it
    from termios import error as TermiosError
except ImportError:                    # pragma: no cover - not POSIX
    class TermiosError(Exception):
        """Stand-in where termios does not exist."""

from fiber_align.hardware import errors as er

CHANNELS = ('x', 'y', 'z')
DEVICE = 'MDT693B'
#: The settings of the rear-panel output limit switch (V): ``vlimit?`` answers one.
LIMIT_SWITCHES_V = (75.0, 100.0, 150.0)
_NUMBER = re.compile(r'\[\s*([-+0-9.eE]+)\s*\]')


def _serial():
    """Import pyserial lazily so the pure core loads without the hardware extra."""
    try:
        import serial
    except ImportError as exc:                      # pragma: no cover - packaging
        raise er.DeviceError(DEVICE, er.NOT_CONNECTED,
                             'pyserial is not installed (pip install .[hardware]): %s'
                             % exc) from None
    return serial


class MDT693B:
    """
    Serial client of one MDT693B (3 channels) or MDT694B (channel x only).

    :param port: serial device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, a pty).
    :param baud: baud rate (115200 on the device).
    :param timeout_s: bound on every reply (s): no prompt within it is a DeviceError.
    """

    def __init__(self, port, baud=115200, timeout_s=0.5):
        """Store the settings; nothing is opened until :meth:`open`."""
        self.port = str(port)
        self.baud = int(baud)
        self.timeout_s = float(timeout_s)
        self._ser = None
        self.prompt = b'>'
        self.ident = ''
        self.transactions = 0

    # -- connection ---------------------------------------------------------------------
    @property
    def is_open(self):
        """Return True while the port is open."""
        return self._ser is not None

    def open(self):
        """
        Open the port, select the present command set (``cm=0``) and turn the echo off.

        :raises DeviceError: the port cannot be opened or the device does not answer.
        """
        serial = _serial()
        self.close()
        try:
            self._ser = serial.Serial(self.port, self.baud, bytesize=serial.EIGHTBITS,
                                      parity=serial.PARITY_NONE,
                                      stopbits=serial.STOPBITS_ONE, timeout=self.timeout_s,
                                      write_timeout=self.timeout_s, xonxoff=False,
                                      rtscts=False, dsrdtr=False)
        except (serial.SerialException, OSError, TermiosError, ValueError) as exc:
            self._ser = None
            raise er.DeviceError(DEVICE, er.PORT_GONE,
                                 'cannot open %s: %s' % (self.port, exc)) from None
        # Resynchronise: whatever mode and echo state the device is in, a bare CR and
        # the two mode commands end with a prompt ('>' or '*') that we read past.
        try:
            try:
                self._ser.reset_input_buffer()
            except (serial.SerialException, OSError, TermiosError) as exc:
                raise er.DeviceError(DEVICE, er.PORT_GONE, 'cannot use %s: %s'
                                     % (self.port, exc)) from None
            for cmd in (b'\r', b'cm=0\r', b'echo=0\r'):
                self._write(cmd)
                self._read_until_prompt(prompts=(b'>', b'*'))
            self.prompt = b'>'
        except er.DeviceError:
            self.close()
            raise
        return self

    def close(self):
        """Close the port (never raises)."""
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a vanished port may fail anyhow
                pass

    def __enter__(self):
        """Open on entry."""
        return self.open()

    def __exit__(self, *exc):
        """Close on exit."""
        self.close()

    # -- transactions -------------------------------------------------------------------
    def _write(self, data):
        serial = _serial()
        if self._ser is None:
            raise er.DeviceError(DEVICE, er.NOT_CONNECTED, 'port %s is not open' % self.port)
        try:
            n = self._ser.write(data)
            self._ser.flush()
        except serial.SerialTimeoutException as exc:
            self.close()
            raise er.DeviceError(DEVICE, er.WRITE_ERROR, 'write to %s timed out after '
                                 '%.3g s: %s' % (self.port, self.timeout_s, exc)) from None
        except (serial.SerialException, OSError, TermiosError) as exc:
            self.close()
            raise er.DeviceError(DEVICE, er.PORT_GONE, 'write to %s failed: %s'
                                 % (self.port, exc)) from None
        if n != len(data):
            self.close()
            raise er.DeviceError(DEVICE, er.WRITE_ERROR, 'wrote %s of %d bytes to %s'
                                 % (n, len(data), self.port))

    def _read_until_prompt(self, prompts=None):
        """Read until a prompt byte; return the bytes before it."""
        serial = _serial()
        prompts = prompts or (self.prompt,)
        buf = bytearray()
        deadline = time.monotonic() + self.timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise er.DeviceError(DEVICE, er.NO_PROMPT, 'no prompt from %s within %.3g s '
                                     '(got %r)' % (self.port, self.timeout_s, bytes(buf)))
            try:
                self._ser.timeout = left
                chunk = self._ser.read(max(1, self._ser.in_waiting or 1))
            except (serial.SerialException, OSError, TermiosError, TypeError,
                    AttributeError) as exc:
                self.close()
                raise er.DeviceError(DEVICE, er.PORT_GONE, 'read from %s failed: %s'
                                     % (self.port, exc)) from None
            if not chunk:
                continue
            buf.extend(chunk)
            for p in prompts:
                if buf.endswith(p):
                    return bytes(buf[:-1])

    def transact(self, command):
        """
        Send one command, return its reply text (echo and prompt removed).

        :raises DeviceError: ``CMD_NOT_DEFINED``, no prompt within the timeout, the port
            is gone or a write failed.
        """
        cmd = command.strip()
        self._write(cmd.encode('ascii') + b'\r')
        # either prompt: a unit left in the compatibility set answers '*' (and one public
        # capture shows '*' with the compatibility mode reported off)
        raw = self._read_until_prompt(prompts=(b'>', b'*')).decode('ascii', 'replace')
        self.transactions += 1
        # an echo (if someone turned it on) repeats the command and its CR first
        if raw.lower().startswith(cmd.lower()):
            raw = raw[len(cmd):]
        text = raw.strip('\r\n ')
        if er.CMD_NOT_DEFINED in text:
            raise er.DeviceError(DEVICE, er.CMD_NOT_DEFINED,
                                 'the device does not know %r' % cmd)
        return text

    def _number(self, command):
        text = self.transact(command)
        m = _NUMBER.search(text)
        if not m:
            raise er.DeviceError(DEVICE, er.BAD_REPLY, '%r answered %r, expected "[ number]"'
                                 % (command, text))
        return float(m.group(1))

    # -- commands -----------------------------------------------------------------------
    def identify(self):
        """Return the ``id?`` text (model, firmware, voltage range, serial, name)."""
        self.ident = self.transact('id?')
        if 'MDT69' not in self.ident:
            raise er.DeviceError(DEVICE, er.WRONG_DEVICE, '%s answered id? with %r'
                                 % (self.port, self.ident[:80]))
        return self.ident

    @property
    def channels(self):
        """Return the channel letters of the identified model (MDT694B: x only)."""
        return ('x',) if 'MDT694' in self.ident else CHANNELS

    def voltage_limit(self):
        """Return the output limit switch setting (V): 75, 100 or 150."""
        return self._number('vlimit?')

    def set_voltage(self, channel, volts):
        """Set one channel's output voltage (V); the caller has checked the value."""
        ch = channel_name(channel)
        self.transact('%svoltage=%.3f' % (ch, volts))

    def get_voltage(self, channel):
        """Read one channel's output voltage back (V, 0.1 V resolution)."""
        return self._number('%svoltage?' % channel_name(channel))

    def set_xyz(self, vx, vy, vz):
        """Set the three channels in one command (V)."""
        self.transact('xyzvoltage=%.3f,%.3f,%.3f' % (vx, vy, vz))


def channel_name(channel):
    """Return ``channel`` as ``x``, ``y`` or ``z`` (raises ValueError otherwise)."""
    ch = str(channel).strip().lower()
    if ch not in CHANNELS:
        raise ValueError('channel must be x, y or z, got %r' % (channel,))
    return ch
