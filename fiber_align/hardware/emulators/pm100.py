# SPDX-License-Identifier: Apache-2.0
r"""
A Thorlabs PM100 power meter on a loopback TCP socket, reading this package's optics.

pyvisa reaches it as ``TCPIP::127.0.0.1::<port>::SOCKET`` (read and write termination
``\n``). SCPI as the PM100 manuals document it, long or short mnemonics, any case:
``*IDN?``, ``*RST``, ``*CLS``, ``SENS:CORR:WAV <nm>`` / ``?``, ``SENS:POW:RANG:AUTO
ON|OFF|1|0`` / ``?``, ``SENS:POW:RANG[:UPP] <W>`` / ``?``, ``SENS:AVER[:COUN] <n>`` /
``?``, ``CONF[:SCAL]:POW`` / ``CONF?``, ``MEAS[:SCAL]:POW?``, ``READ?``, ``INIT``,
``FETC?``, ``SYST:ERR?`` (``0,"No error"`` or ``-113,"Undefined header"``, ...). An
unknown header queues an error and sends nothing, as SCPI instruments do.

A measurement averages ``SENS:AVER:COUN`` samples of ``sample_time_s`` each (3 ms: "each
sample taking approximately 3 ms", PM100USB documentation), so the reply comes that much
later; every sample is the package's detector (noise floor, relative intensity noise,
first-order averaging, saturation) reading the coupled power at the emulated bimorph's
position at that instant. With auto range off, a power above the range reads the range.
The wavelength does not change the emulated coupling (the link's ``wavelength_m`` does);
it is stored and read back.

:meth:`PM100Emulator.unplug` drops every connection and refuses new ones until
:meth:`plug`; :attr:`PM100Emulator.silent` true keeps the connections but answers nothing
(a meter that hangs: every query times out).
"""

import socket
import threading
import time

IDN = 'Thorlabs,PM100USB,EMU000002,1.7.0 (fiber_align emulator)'
KEYWORDS = ('SENSe', 'CORRection', 'WAVelength', 'POWer', 'DC', 'RANGe', 'UPPer', 'AUTO',
            'AVERage', 'COUNt', 'CONFigure', 'SCALar', 'MEASure', 'READ', 'FETCh',
            'INITiate', 'IMMediate', 'SYSTem', 'ERRor', 'NEXT')
_SHORT = {}
for _k in KEYWORDS:
    _s = ''.join(c for c in _k if c.isupper())
    _SHORT[_s] = _s
    _SHORT[_k.upper()] = _s
OPTIONAL = ('SCAL', 'IMM', 'DC', 'NEXT')


def normalise(header):
    """Return the short, upper-case form of a SCPI header, optional nodes removed."""
    h = header.strip().upper()
    query = h.endswith('?')
    h = h.rstrip('?').lstrip(':')
    if h.startswith('*'):
        return h + ('?' if query else '')
    parts = []
    for tok in h.split(':'):
        s = _SHORT.get(tok)
        if s is None:
            raise KeyError(tok)
        if s not in OPTIONAL:
            parts.append(s)
    return ':'.join(parts) + ('?' if query else '')


class PM100Emulator:
    """
    Serve the PM100 SCPI subset on 127.0.0.1 until :meth:`stop`.

    :param bench: the :class:`~fiber_align.hardware.emulators.physics.Bench` to read.
    :param port: TCP port, 0 = pick a free one (see :attr:`port`).
    :param sample_time_s: time of one averaged sample (s).
    """

    def __init__(self, bench, port=0, sample_time_s=3e-3):
        """Bind, listen and start the accept thread."""
        self.bench = bench
        self.sample_time_s = float(sample_time_s)
        self.wavelength_nm = 1550.0
        self.auto_range = True
        self.range_w = 0.01
        self.average_count = 1
        self.errors = []
        self.readings = 0
        self.plugged = True
        self.silent = False             # connected but answering nothing
        self._stop = threading.Event()
        self._conns = set()
        self._lock = threading.Lock()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind(('127.0.0.1', int(port)))
        self._sock.listen(4)
        self._sock.settimeout(0.05)
        self.port = self._sock.getsockname()[1]
        self.resource = 'TCPIP::127.0.0.1::%d::SOCKET' % self.port
        self._threads = []
        t = threading.Thread(target=self._accept, name='pm100-accept', daemon=True)
        t.start()
        self._threads.append(t)

    def unplug(self):
        """Drop every connection and refuse new ones."""
        self.plugged = False
        with self._lock:
            conns = list(self._conns)
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def plug(self):
        """Accept connections again."""
        self.plugged = True

    def stop(self, timeout_s=2.0):
        """Stop serving and close every socket; bounded by ``timeout_s``."""
        self._stop.set()
        self.unplug()
        deadline = time.monotonic() + timeout_s
        for t in list(self._threads):
            t.join(max(0.0, deadline - time.monotonic()))
        self._sock.close()

    def _accept(self):
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            if not self.plugged:
                conn.close()
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(0.05)
            with self._lock:
                self._conns.add(conn)
            t = threading.Thread(target=self._serve, args=(conn,), name='pm100-conn',
                                 daemon=True)
            t.start()
            self._threads.append(t)

    def _serve(self, conn):
        buf = b''
        try:
            while not self._stop.is_set() and self.plugged:
                try:
                    data = conn.recv(4096)
                except socket.timeout:
                    continue
                except OSError:
                    return
                if not data:
                    return
                buf += data
                if self.silent:
                    buf = b''
                    continue
                while b'\n' in buf:
                    line, buf = buf.split(b'\n', 1)
                    for cmd in line.decode('ascii', 'replace').split(';'):
                        reply = self.handle(cmd)
                        if reply is not None and self.plugged:
                            conn.sendall(reply.encode('ascii') + b'\n')
        except OSError:
            return
        finally:
            with self._lock:
                self._conns.discard(conn)
            try:
                conn.close()
            except OSError:
                pass

    # -- SCPI -----------------------------------------------------------------------------
    def _error(self, code, text):
        self.errors.append((code, text))
        del self.errors[:-30]

    def measure_w(self):
        """Take ``average_count`` samples ``sample_time_s`` apart; return their mean (W)."""
        n = max(1, int(self.average_count))
        total = 0.0
        t_next = time.monotonic()
        for _ in range(n):
            t_next += self.sample_time_s
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            total += self.bench.detector_sample(self.sample_time_s)
        p = total / n
        if not self.auto_range:
            p = min(p, self.range_w)
        self.readings += 1
        return p

    def handle(self, command):
        """Execute one SCPI command; return the reply text or None."""
        text = command.strip()
        if not text:
            return None
        head, _, arg = text.partition(' ')
        arg = arg.strip()
        try:
            h = normalise(head)
        except KeyError:
            self._error(-113, 'Undefined header')
            return None
        try:
            return self._execute(h, arg)
        except ValueError:
            self._error(-224, 'Illegal parameter value')
            return None

    def _execute(self, h, arg):
        if h == '*IDN?':
            return IDN
        if h in ('*RST', '*CLS'):
            if h == '*RST':
                self.auto_range, self.average_count, self.wavelength_nm = True, 1, 1550.0
            self.errors = []
            return None
        if h == 'SYST:ERR?':
            if not self.errors:
                return '0,"No error"'
            code, msg = self.errors.pop(0)
            return '%d,"%s"' % (code, msg)
        if h == 'SENS:CORR:WAV':
            v = float(arg)
            if not 200.0 <= v <= 20000.0:
                raise ValueError(arg)
            self.wavelength_nm = v
            return None
        if h == 'SENS:CORR:WAV?':
            return '%.6g' % self.wavelength_nm
        if h == 'SENS:POW:RANG:AUTO':
            a = arg.upper()
            if a not in ('ON', 'OFF', '1', '0'):
                raise ValueError(arg)
            self.auto_range = a in ('ON', '1')
            return None
        if h == 'SENS:POW:RANG:AUTO?':
            return '1' if self.auto_range else '0'
        if h in ('SENS:POW:RANG', 'SENS:POW:RANG:UPP'):
            v = float(arg)
            if not v > 0:
                raise ValueError(arg)
            self.range_w, self.auto_range = v, False
            return None
        if h in ('SENS:POW:RANG?', 'SENS:POW:RANG:UPP?'):
            return '%.6E' % self.range_w
        if h in ('SENS:AVER', 'SENS:AVER:COUN'):
            n = int(float(arg))
            if not 1 <= n <= 10000:
                raise ValueError(arg)
            self.average_count = n
            return None
        if h in ('SENS:AVER?', 'SENS:AVER:COUN?'):
            return '%d' % self.average_count
        if h in ('CONF:POW', 'INIT'):
            return None
        if h == 'CONF?':
            return 'POW'
        if h in ('MEAS:POW?', 'MEAS?', 'READ?', 'FETC?'):
            return '%.6E' % self.measure_w()
        self._error(-113, 'Undefined header')
        return None
