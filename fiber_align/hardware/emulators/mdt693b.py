# SPDX-License-Identifier: Apache-2.0
"""
An MDT693B piezo controller on a pseudo-terminal, driving this package's bimorph.

Clients open :attr:`MDT693BEmulator.port` (a stable symlink to the pty's slave, like
``/dev/serial/by-id/...``; :attr:`slave_path` is the pty itself) at any baud rate. The
protocol is the one :mod:`fiber_align.hardware.mdt693b` describes: CR-terminated
commands (line feeds ignored, case-insensitive), echo of every received character while
``echo=1`` (the power-on state of the units in the captures), the prompt ``>`` (``*``
in the compatibility set, ``cm=1``), ``[ value]`` replies, ``CMD_NOT_DEFINED`` for
anything else. Present set: ``xvoltage=``/``?`` (y, z), ``allvoltage=``,
``xyzvoltage=``/``?``, ``xmin=``/``?``, ``xmax=``/``?`` (y, z), ``sysmin?``,
``sysmax?``, ``vlimit?``, ``id?``, ``serial?``, ``friendly?``, ``echo=``/``?``,
``cm=``/``?``, ``restore``. Compatibility set (also accepted in either mode, as
``mdt69x`` relies on): ``XV``/``YV``/``ZV``/``AV`` <V>, ``XR``/``YR``/``ZR``,
``XH``/``XL`` <V> and ``XH?``/``XL?`` (y, z), ``I``, ``%``, ``E0``/``E1``.

A set value is clamped to the channel's [min, max] (0 V .. the limit switch), as the
device does; the output then follows with this package's amplifier slew and the
bimorph (hysteresis, resonance) in wall-clock time (:mod:`.physics`). Every voltage
command as received (the raw text and the parsed float, before any clamping) is appended
to :attr:`MDT693BEmulator.command_log`, which the safety tests inspect.

:meth:`unplug` closes the pty (clients see their port vanish); :meth:`plug` makes a new
pty and points the symlink at it, as a USB re-enumeration does.

Link timing (a pty moves bytes at once; the real link does not): with ``baud`` > 0 a
command takes effect ``10 * bytes / baud`` s after its first byte (8N1: 10 bits a byte,
the CR counted) and its reply (prompt included) is written ``turnaround_s`` later plus
the reply's own ``10 * bytes / baud``; one command at a time, as the firmware answers
them. The echo is not timed (it travels back while the command comes in).
"""

import os
import re
import select
import tempfile
import threading
import time
import tty

PROMPT = b'>'
COMPAT_PROMPT = b'*'
ERROR = b'CMD_NOT_DEFINED'
_FLOAT = r'([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf(?:inity)?|nan)'


class MDT693BEmulator:
    """
    Serve the MDT693B protocol on a pty until :meth:`stop`.

    :param bench: the :class:`~fiber_align.hardware.emulators.physics.Bench` whose
        channels this amplifier drives.
    :param model: ``MDT693B`` (x, y, z) or ``MDT694B`` (x only).
    :param echo: echo at start (True, as the captured units).
    :param compat: start in the compatibility command set.
    :param link_dir: directory of the stable symlink (default: a new temporary one).
    :param response_delay_s: extra delay (s) before each reply, to emulate a slow unit.
    :param baud: the link's rate (baud) whose byte times are modelled; 0: none.
    :param turnaround_s: the firmware's time (s) from a command's CR to its reply.
    """

    def __init__(self, bench, model='MDT693B', echo=True, compat=False, link_dir=None,
                 response_delay_s=0.0, baud=0, turnaround_s=0.0):
        """Open the pty and start serving."""
        if model not in ('MDT693B', 'MDT694B'):
            raise ValueError('model must be MDT693B or MDT694B, got %r' % model)
        self.bench = bench
        self.model = model
        self.channels = ('x',) if model == 'MDT694B' else ('x', 'y', 'z')
        self.echo = bool(echo)
        self.compat = bool(compat)
        self.response_delay_s = float(response_delay_s)
        self.byte_s = 10.0 / float(baud) if baud and float(baud) > 0 else 0.0
        self.turnaround_s = float(turnaround_s)
        self.vmin = {c: 0.0 for c in self.channels}
        self.vmax = {c: bench.v_limit for c in self.channels}
        self.command_log = []           # (monotonic s, channel, raw text, parsed float)
        self.commands = 0
        self._t_cmd = 0.0
        self._own_dir = link_dir is None
        self._dir = tempfile.mkdtemp(prefix='mdt693b-') if link_dir is None else link_dir
        self.port = os.path.join(self._dir, 'ttyMDT693B')
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.master = self._slave_keep = None
        self.slave_path = None
        self._gen = 0
        self.plug()
        self._thread = threading.Thread(target=self._serve, name='mdt693b-emulator',
                                        daemon=True)
        self._thread.start()

    # -- plugging -------------------------------------------------------------------------
    def plug(self):
        """Create a new pty (if unplugged) and point :attr:`port` at its slave."""
        with self._lock:
            if self.master is not None:
                return
            master, slave = os.openpty()
            tty.setraw(slave)
            tty.setraw(master)
            self.slave_path = os.ttyname(slave)
            tmp = self.port + '.new'
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.slave_path, tmp)
            os.replace(tmp, self.port)
            # keep a slave descriptor open so a client closing its port does not
            # hang the master up (EIO) between two clients
            self.master, self._slave_keep, self._buf = master, slave, bytearray()
            self._gen += 1          # a new pty (its fd number may be the old one's)

    def unplug(self):
        """Close the pty: every client's port is gone (reads fail, writes fail)."""
        with self._lock:
            for fd in (self.master, self._slave_keep):
                if fd is not None:
                    try:
                        os.close(fd)
                    except OSError:
                        pass
            self.master = self._slave_keep = None

    @property
    def plugged(self):
        """Return True while the pty exists."""
        return self.master is not None

    def stop(self, timeout_s=2.0):
        """Stop serving, close the pty, remove the symlink; bounded by ``timeout_s``."""
        self._stop.set()
        self._thread.join(timeout_s)
        self.unplug()
        for p in (self.port,):
            try:
                os.unlink(p)
            except OSError:
                pass
        if self._own_dir:
            try:
                os.rmdir(self._dir)
            except OSError:
                pass

    # -- serving ----------------------------------------------------------------------------
    def _serve(self):
        while not self._stop.is_set():
            fd = self.master
            if fd is None:
                time.sleep(0.01)
                continue
            try:
                r, _, _ = select.select([fd], [], [], 0.05)
                if not r:
                    continue
                data = os.read(fd, 4096)
            except (OSError, ValueError):
                time.sleep(0.01)         # unplugged under us
                continue
            if not data:
                continue
            gen = self._gen         # the pty these bytes came from (plug() makes a new one)
            out = bytearray(data) if self.echo else bytearray()
            for b in data:
                if b == 0x0D:            # CR ends a command
                    line = self._buf.decode('ascii', 'replace')
                    self._buf = bytearray()
                    self._sleep(self.byte_s * (len(line) + 1))
                    reply = self._handle(line)
                    self._sleep(self.turnaround_s + self.response_delay_s
                                + self.byte_s * len(reply))
                    out += reply
                    self._send(fd, out, gen)
                    out = bytearray()
                elif b == 0x0A:          # LF ignored
                    continue
                else:
                    self._buf.append(b)
            if out:
                self._send(fd, out, gen)

    @staticmethod
    def _sleep(seconds):
        if seconds > 0:
            time.sleep(seconds)

    def _send(self, fd, data, gen):
        """Write ``data`` to the pty it answers, never to a pty plugged in since."""
        with self._lock:
            if gen != self._gen or self.master is None:
                return
        try:
            os.write(fd, bytes(data))
        except OSError:
            pass

    def _prompt(self):
        return COMPAT_PROMPT if self.compat else PROMPT

    def _handle(self, line):
        """Return the reply bytes (prompt included) to one command line."""
        self.commands += 1
        self._t_cmd = time.monotonic()      # one time for every channel of one command
        prompt = self._prompt()
        cmd = line.strip()
        try:
            reply = self._dispatch(cmd)
        except (ValueError, KeyError, IndexError):
            reply = None
        if reply is None:
            return ERROR + prompt
        return reply + prompt

    def _set(self, ch, text, value):
        with self._lock:
            self.command_log.append((self._t_cmd, ch, text, value))
        v = min(max(value, self.vmin[ch]), self.vmax[ch])
        if v != v:                                   # NaN: the device ignores it
            return
        self.bench.command(ch, v)

    def _read(self, ch):
        return b'[%6.1f]\r' % self.bench.output_v(ch)

    def _dispatch(self, cmd):
        low = cmd.lower()
        chans = self.channels
        m = re.fullmatch(r'([xyz])voltage=\s*' + _FLOAT, low)
        if m and m.group(1) in chans:
            self._set(m.group(1), cmd, float(m.group(2)))
            return b''
        m = re.fullmatch(r'([xyz])voltage\?', low)
        if m and m.group(1) in chans:
            return self._read(m.group(1))
        m = re.fullmatch(r'allvoltage=\s*' + _FLOAT, low)
        if m:
            for ch in chans:
                self._set(ch, cmd, float(m.group(1)))
            return b''
        m = re.fullmatch(r'xyzvoltage=\s*%s\s*,\s*%s\s*,\s*%s' % (_FLOAT, _FLOAT, _FLOAT),
                         low)
        if m and len(chans) == 3:
            for ch, val in zip(chans, m.groups()):
                self._set(ch, cmd, float(val))
            return b''
        if low == 'xyzvoltage?' and len(chans) == 3:
            return b'[%s]\r' % b', '.join(b'%6.1f' % self.bench.output_v(c) for c in chans)
        m = re.fullmatch(r'([xyz])(min|max)=\s*' + _FLOAT, low)
        if m and m.group(1) in chans:
            return self._limit(m.group(1), m.group(2), float(m.group(3)))
        m = re.fullmatch(r'([xyz])(min|max)\?', low)
        if m and m.group(1) in chans:
            d = self.vmin if m.group(2) == 'min' else self.vmax
            return b'[%6.1f]\r' % d[m.group(1)]
        if low in ('sysmin?', 'sysmax?'):
            return b'[%6.1f]\r' % (0.0 if low == 'sysmin?' else self.bench.v_limit)
        if low in ('vlimit?', '%'):
            return b'[%4d]\r' % int(round(self.bench.v_limit))
        if low in ('id?', 'i'):
            return (b'\r\r\rModel %s Piezo Control Module\rFirmware Version: 1.09\r'
                    b'Voltage Range: %dV\rSerial#: EMU000001\rName: fiber_align emulator\r'
                    % (self.model.encode(), int(round(self.bench.v_limit))))
        if low == 'serial?':
            return b'EMU000001\r'
        if low == 'friendly?':
            return b'fiber_align emulator\r'
        m = re.fullmatch(r'(?:echo=|e)([01])', low)
        if m:
            self.echo = m.group(1) == '1'
            return b''
        if low == 'echo?':
            return b'[Echo %s]\r' % (b'On' if self.echo else b'Off')
        m = re.fullmatch(r'cm=([01])', low)
        if m:
            self.compat = m.group(1) == '1'
            return b''
        if low == 'cm?':
            return b'[MDT693A Compatibility Mode %s]\r' % (b'On' if self.compat else b'Off')
        if low == 'restore':
            for ch in chans:
                self.vmin[ch], self.vmax[ch] = 0.0, self.bench.v_limit
            self.echo, self.compat = True, False
            return b''
        # compatibility set
        m = re.fullmatch(r'([xyza])v\s*' + _FLOAT, low)
        if m:
            targets = chans if m.group(1) == 'a' else (m.group(1),)
            if not set(targets) <= set(chans):
                return None
            for ch in targets:
                self._set(ch, cmd, float(m.group(2)))
            return b''
        m = re.fullmatch(r'([xyz])r\??', low)
        if m and m.group(1) in chans:
            return self._read(m.group(1))
        m = re.fullmatch(r'([xyz])([hl])\s*' + _FLOAT, low)
        if m and m.group(1) in chans:
            return self._limit(m.group(1), 'max' if m.group(2) == 'h' else 'min',
                               float(m.group(3)))
        m = re.fullmatch(r'([xyz])([hl])\?', low)
        if m and m.group(1) in chans:
            d = self.vmax if m.group(2) == 'h' else self.vmin
            return b'[%6.1f]\r' % d[m.group(1)]
        return None

    def _limit(self, ch, which, value):
        if not value == value or not 0.0 <= value <= self.bench.v_limit:
            return None
        if which == 'min':
            if value > self.vmax[ch]:
                return None
            self.vmin[ch] = value
        else:
            if value < self.vmin[ch]:
                return None
            self.vmax[ch] = value
        return b''
