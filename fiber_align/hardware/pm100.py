# SPDX-License-Identifier: Apache-2.0
r"""
Thorlabs PM100 family power meter (PM100D, PM100USB, PM101, ...) over SCPI with pyvisa.

The pure-Python backend ``@py`` (pyvisa-py) reaches the meter as USBTMC
(``USB0::0x1313::0x8078::P0001234::INSTR``, needs pyusb), serial
(``ASRL/dev/ttyUSB0::INSTR``) or a TCP socket (``TCPIP::127.0.0.1::5025::SOCKET``, the
emulator). Socket and serial resources get ``\n`` read and write termination.

:meth:`PM100.configure` sends ``SENS:CORR:WAV <nm>``, ``SENS:POW:RANG:AUTO ON``,
``SENS:AVER:COUN <n>`` and ``CONF:POW`` and checks ``SYST:ERR?``; :meth:`PM100.read_w`
queries ``MEAS:POW?`` (W). Each averaged sample takes about 3 ms on the meter, so one
reading takes about ``3 ms * averaging_count`` plus the transfer. A meter that goes away
raises :class:`~fiber_align.hardware.errors.DeviceError` (reason ``no reply within
timeout`` or ``port gone``) within ``timeout_s``; :meth:`PM100.reconnect` opens it again.
SI units: W, m, s.
"""

import math

from fiber_align.hardware import errors as er

DEVICE = 'PM100'


def _pyvisa():
    try:
        import pyvisa
    except ImportError as exc:                      # pragma: no cover - packaging
        raise er.DeviceError(DEVICE, er.NOT_CONNECTED, 'pyvisa is not installed (pip '
                             'install .[hardware]): %s' % exc) from None
    return pyvisa


class PM100:
    """
    One PM100 power meter.

    :param resource: VISA resource string.
    :param wavelength_m: wavelength correction (m), sent in nm.
    :param averaging_count: samples averaged per reading (each ~3 ms).
    :param timeout_s: bound on every query (s).
    :param backend: pyvisa backend, ``@py`` = pyvisa-py.
    """

    def __init__(self, resource, wavelength_m=1.55e-6, averaging_count=1, timeout_s=0.5,
                 backend='@py'):
        """Store the settings; nothing is opened until :meth:`open`."""
        if not (math.isfinite(wavelength_m) and 200e-9 <= wavelength_m <= 20e-6):
            raise ValueError('wavelength_m must be within 200 nm .. 20 um, got %r'
                             % (wavelength_m,))
        if int(averaging_count) < 1:
            raise ValueError('averaging_count must be >= 1')
        self.resource = str(resource)
        self.wavelength_m = float(wavelength_m)
        self.averaging_count = int(averaging_count)
        self.timeout_s = float(timeout_s)
        self.backend = backend
        self._rm = None
        self._inst = None
        self.ident = ''
        self.readings = 0

    @classmethod
    def from_params(cls, p):
        """Build from the ``power_meter`` keys of ``config/hardware.yaml``."""
        return cls(p.get('resource', 'TCPIP::127.0.0.1::5025::SOCKET'),
                   float(p.get('wavelength_m', 1.55e-6)), int(p.get('averaging_count', 1)),
                   float(p.get('timeout_s', 0.5)), p.get('visa_backend', '@py'))

    @property
    def is_open(self):
        """Return True while the resource is open."""
        return self._inst is not None

    def _fail(self, exc, what):
        """Close and turn a pyvisa/OS exception into a DeviceError."""
        pyvisa = _pyvisa()
        self.close()
        if isinstance(exc, pyvisa.errors.VisaIOError) and \
                exc.error_code == pyvisa.constants.StatusCode.error_timeout:
            return er.DeviceError(DEVICE, er.NO_REPLY, '%s: no reply from %s within %.3g s'
                                  % (what, self.resource, self.timeout_s))
        return er.DeviceError(DEVICE, er.PORT_GONE, '%s on %s failed: %s'
                              % (what, self.resource, exc))

    def open(self):
        """Open the resource and identify the meter (``*IDN?``)."""
        pyvisa = _pyvisa()
        self.close()
        try:
            self._rm = pyvisa.ResourceManager(self.backend)
            inst = self._rm.open_resource(self.resource, open_timeout=int(
                self.timeout_s * 1000))
            inst.timeout = max(1, int(round(self.timeout_s * 1000)))
            if '::SOCKET' in self.resource.upper() or self.resource.upper().startswith(
                    'ASRL'):
                inst.read_termination = '\n'
                inst.write_termination = '\n'
            self._inst = inst
        except (pyvisa.errors.Error, OSError, ValueError) as exc:
            raise self._fail(exc, 'open') from None
        self.ident = self.query('*IDN?')
        if 'PM10' not in self.ident.upper():
            idn = self.ident
            self.close()
            raise er.DeviceError(DEVICE, er.WRONG_DEVICE, '%s answered *IDN? with %r'
                                 % (self.resource, idn[:80]))
        return self

    def close(self):
        """Close the resource (never raises)."""
        inst, self._inst = self._inst, None
        rm, self._rm = self._rm, None
        for obj in (inst, rm):
            if obj is not None:
                try:
                    obj.close()
                except Exception:  # noqa: BLE001 - a vanished meter may fail to close
                    pass

    def reconnect(self):
        """Close and open again, then configure; return the ``*IDN?`` text."""
        self.close()
        self.open()
        self.configure()
        return self.ident

    def write(self, command):
        """Send one SCPI command."""
        pyvisa = _pyvisa()
        if self._inst is None:
            raise er.DeviceError(DEVICE, er.NOT_CONNECTED, '%s is not open' % self.resource)
        try:
            self._inst.write(command)
        except (pyvisa.errors.Error, OSError) as exc:
            raise self._fail(exc, 'write %r' % command) from None

    def query(self, command):
        """Send one SCPI query; return the reply text (stripped)."""
        pyvisa = _pyvisa()
        if self._inst is None:
            raise er.DeviceError(DEVICE, er.NOT_CONNECTED, '%s is not open' % self.resource)
        try:
            return self._inst.query(command).strip()
        except (pyvisa.errors.Error, OSError) as exc:
            raise self._fail(exc, 'query %r' % command) from None

    def errors(self, limit=20):
        """Drain ``SYST:ERR?``; return the list of ``(code, text)`` (empty = none)."""
        out = []
        for _ in range(limit):
            reply = self.query('SYST:ERR?')
            code, _, text = reply.partition(',')
            try:
                c = int(code)
            except ValueError:
                raise er.DeviceError(DEVICE, er.BAD_REPLY, 'SYST:ERR? answered %r'
                                     % reply) from None
            if c == 0:
                break
            out.append((c, text.strip().strip('"')))
        return out

    def configure(self):
        """Set wavelength, auto range, averaging and power mode; raise on any SCPI error."""
        self.write('*CLS')
        self.write('SENS:CORR:WAV %.3f' % (self.wavelength_m * 1e9))
        self.write('SENS:POW:RANG:AUTO ON')
        self.write('SENS:AVER:COUN %d' % self.averaging_count)
        self.write('CONF:POW')
        errs = self.errors()
        if errs:
            raise er.DeviceError(DEVICE, er.INSTRUMENT_ERROR, 'configure: %s'
                                 % '; '.join('%d %s' % e for e in errs))
        return dict(ident=self.ident, wavelength_m=self.wavelength_m,
                    averaging_count=self.averaging_count)

    def read_w(self):
        """Measure and return the optical power (W)."""
        reply = self.query('MEAS:POW?')
        try:
            p = float(reply)
        except ValueError:
            raise er.DeviceError(DEVICE, er.BAD_REPLY, 'MEAS:POW? answered %r'
                                 % reply) from None
        if not math.isfinite(p) or abs(p) > 1e30:
            raise er.DeviceError(DEVICE, er.BAD_REPLY, 'MEAS:POW? answered %r (over range)'
                                 % reply)
        self.readings += 1
        return p
