# SPDX-License-Identifier: Apache-2.0
"""
The ``power_meter`` node's reading of a PM100, pure (no rclpy): :class:`MeterReader`.

A thread of its own connects, reads at ``rate_hz`` (Hz; pyvisa calls block for about 3 ms
per averaged sample), keeps the last 10 entries of the meter's ``SYST:ERR?`` queue, read
every ``errors_period_s`` (s), and reopens a lost meter every ``reconnect_period_s`` (s),
until stopped. The node gives it ``publish(p_w)``, which returns the reading's stamp (s)
or ``None`` once the process stops (the thread then ends), and ``on_health(level,
message)``, called on each change of level.
"""

import threading
import time

from fiber_align.control.health import ERROR, OK, STALE
from fiber_align.hardware import errors as er


class MeterReader:
    """Read a PM100 on a thread; its health, rate and error queue for ``/diagnostics``."""

    def __init__(self, meter, rate_hz, errors_period_s, reconnect_period_s, publish,
                 on_health):
        """Prepare the thread (:meth:`start` starts it); ``meter``: a :class:`PM100`."""
        self.meter, self.period_s = meter, 1.0 / float(rate_hz)
        self.errors_period_s = float(errors_period_s)
        self.reconnect_period_s = float(reconnect_period_s)
        self._publish, self._on_health = publish, on_health
        self.lock = threading.Lock()
        self.level, self.message = STALE, 'connecting to the meter'
        self.readings = 0
        self.last_stamp = None
        self.times = []
        self.meter_errors = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.loop, name='power_meter', daemon=True)

    def start(self):
        """Start the reading thread."""
        self.thread.start()

    def set_health(self, level, message):
        """Record the health; call ``on_health`` when the level changes (not at the stop)."""
        with self.lock:
            changed = level != self.level
            self.level, self.message = level, message
        if changed and not self.stop.is_set():
            self._on_health(level, message)

    def loop(self):
        """Connect, read at ``rate_hz``, reconnect after a loss; until :attr:`stop`."""
        while not self.stop.is_set():
            try:
                self.meter.open()
                self.meter.configure()
                self.set_health(OK, 'reading %s (%s)' % (self.meter.resource, self.meter.ident))
                t_next = time.monotonic()
                t_err = t_next
                while not self.stop.is_set():
                    self._read()
                    now = time.monotonic()
                    if now - t_err >= self.errors_period_s:
                        t_err = now
                        errs = self.meter.errors()
                        if errs:
                            with self.lock:
                                self.meter_errors = (self.meter_errors + errs)[-10:]
                    t_next += self.period_s
                    delay = t_next - time.monotonic()
                    if delay > 0:
                        self.stop.wait(delay)
                    else:
                        t_next = time.monotonic()
            except er.DeviceError as exc:
                self.meter.close()
                self.set_health(ERROR, str(exc))
                self.stop.wait(self.reconnect_period_s)
        self.meter.close()

    def _read(self):
        """Read and publish one reading (W); note its stamp (s) and arrival."""
        t = self._publish(self.meter.read_w())
        if t is None:
            return
        with self.lock:
            self.readings += 1
            self.last_stamp = t
            self.times.append(time.monotonic())
            del self.times[:-200]

    def achieved_rate_hz(self):
        """Return the reading rate (Hz) over the last second (0 when none)."""
        with self.lock:
            now = time.monotonic()
            recent = [t for t in self.times if now - t <= 1.0]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / (recent[-1] - recent[0])

    def status(self):
        """Return ``(level, message, values)``: the health and its figures (text values)."""
        rate = self.achieved_rate_hz()
        with self.lock:
            return self.level, self.message, {
                'rate_hz': '%.2f' % rate, 'readings': str(self.readings),
                'last_stamp_s': '' if self.last_stamp is None else '%.6f' % self.last_stamp,
                'meter_errors': '; '.join('%d %s' % e for e in self.meter_errors)}

    def close(self, timeout_s):
        """Stop the thread (waiting at most ``timeout_s`` s) and close the meter."""
        self.stop.set()
        self.thread.join(timeout_s)
        self.meter.close()


#: Sensorless: the most control periods one set of readings advances the sequencer's clock.
MAX_GAP_PERIODS = 1.5


class ReadingSets:
    """
    Several meters' readings (W) as one set per step of a sensorless sequencer, and its clock.

    Each meter reads on its own clock. A set goes out when every meter has a reading in
    it; a second reading of a meter before the others' goes out with what the set has
    (``None`` for a meter without a reading: after a run of them, the sequencer's
    ``sensor_timeout_s`` names that meter silent). One meter: every reading is a set.
    The sequencer's clock (s) starts at 0 and advances by the wall time between two sets,
    at most :data:`MAX_GAP_PERIODS` control periods (an overrun is not a jump).
    """

    def __init__(self, n, period_s):
        """Hold no reading of any of the ``n`` meters yet; ``period_s``: the control period."""
        self.pending = [None] * int(n)
        self.max_gap_s = MAX_GAP_PERIODS * float(period_s)
        self.t_s, self._wall = None, None

    def add(self, j, value_w, wall_s):
        """Add meter ``j``'s reading (W) at ``wall_s`` (s); return ``(t_s, set)`` or None."""
        out = None
        if self.pending[j] is not None:     # a repeat before the others: the set as it is
            out, self.pending = self.pending, [None] * len(self.pending)
        self.pending[j] = float(value_w)
        if out is None and all(v is not None for v in self.pending):
            out, self.pending = self.pending, [None] * len(self.pending)
        if out is None:
            return None
        self.t_s = 0.0 if self.t_s is None else self.t_s + min(max(wall_s - self._wall, 0.0),
                                                               self.max_gap_s)
        self._wall = wall_s
        return self.t_s, out
