# SPDX-License-Identifier: Apache-2.0
"""
Cycle figures of a node's per-sample work: achieved rate, missed cycles, latency.

Every node of the control loop counts the samples it acts on (:class:`CycleStats`) and
reports, each ``/diagnostics`` period, for the window since the last report: the achieved
rate (Hz), the share of sample periods it did not act on (1) and the p50/p99 latency (s)
from the sample to its output (the plant: from publishing a sample to the drive that
answers it, the loop's sample-to-drive latency). No allocation per sample: a preallocated
buffer and a few integers (the 1 kHz loop's budget is tens of microseconds per node).
"""

import numpy as np

#: Keys the figures are reported under on /diagnostics (units in the names).
KEYS = ('cycle.achieved_rate_hz', 'cycle.missed_share', 'cycle.latency_p50_s',
        'cycle.latency_p99_s', 'cycle.samples')


class CycleStats:
    """
    Windowed cycle figures of one node (pure: the caller passes the clock readings).

    :param rate_hz: the loop's nominal rate (Hz).
    :param capacity: latencies kept per window (more samples are counted, not kept).
    """

    def __init__(self, rate_hz, capacity=None):
        """Start empty; the first window begins at the first :meth:`window` call."""
        self.period_ns = int(round(1e9 / float(rate_hz)))
        self.rate_hz = float(rate_hz)
        self.lat = np.empty(int(capacity or 4 * rate_hz + 16))
        self.n = 0
        self.k_prev = None          # sample index acted on last in the previous window
        self.k_last = None
        self.t0_ns = None

    def index(self, stamp_ns):
        """Return the sample index of a realtime stamp (ns; stamps are k periods apart)."""
        return (int(stamp_ns) + self.period_ns // 2) // self.period_ns

    def record(self, latency_s, index=None):
        """
        Count one sample acted on.

        :param latency_s: its latency (s) from the sample to this node's output.
        :param index: its sample index (:meth:`index`), if the node knows it: the missed
            share is then counted in samples, else from the wall-clock window.
        """
        n = self.n
        if n < self.lat.size:
            self.lat[n] = latency_s
        self.n = n + 1
        if index is not None:
            self.k_last = index

    def window(self, now_ns):
        """
        Return the figures of the window ending now (dict keyed by :data:`KEYS`).

        :param now_ns: a monotonic clock reading (ns); the next window starts here.
        """
        n, t0 = self.n, self.t0_ns
        out = {'cycle.samples': n}
        if t0 is not None and now_ns > t0:
            dt = (now_ns - t0) * 1e-9
            out['cycle.achieved_rate_hz'] = n / dt
            if n and self.k_last is not None and self.k_prev is not None:
                expected = self.k_last - self.k_prev
            else:
                expected = int(round(dt * self.rate_hz))
            out['cycle.missed_share'] = max(0.0, 1.0 - n / expected) if expected > 0 \
                else 0.0
        if n:
            lat = self.lat[:min(n, self.lat.size)]
            p50, p99 = np.percentile(lat, (50, 99))
            out['cycle.latency_p50_s'] = float(p50)
            out['cycle.latency_p99_s'] = float(p99)
        self.n = 0
        self.t0_ns = now_ns
        if self.k_last is not None:
            self.k_prev = self.k_last
        return out


def loop_summary(lat, periods, missed, skipped, samples):
    """
    Return the realtime loop statistics of a run (the plant's, for the summary).

    :param lat: sample-to-drive latencies (s) since the statistics started.
    :param periods: sample periods counted.
    :param missed: ticks with no new drive.
    :param skipped: periods skipped by late ticks.
    :param samples: samples published.
    :returns: dict with ``samples``, ``periods``, ``latency_n``, ``missed_cycles``
        (``missed_no_drive`` plus ``missed_late_tick``), ``missed_share`` (1), and
        ``latency_p50_s``, ``latency_p99_s``, ``latency_max_s`` (s) when there is one.
    """
    total = missed + skipped
    out = {'samples': int(samples), 'periods': int(periods), 'latency_n': int(lat.size),
           'missed_cycles': int(total), 'missed_no_drive': int(missed),
           'missed_late_tick': int(skipped),
           'missed_share': float(total) / periods if periods else 0.0}
    if lat.size:
        p50, p99 = np.percentile(lat, (50, 99))
        out.update(latency_p50_s=float(p50), latency_p99_s=float(p99),
                   latency_max_s=float(lat.max()))
    return out
