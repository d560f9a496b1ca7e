# SPDX-License-Identifier: Apache-2.0
"""
Cycle figures of a node's per-sample work: achieved rate, missed cycles, latency.

Every node of the control loop counts the samples it acts on (:class:`CycleStats`) and
reports, each ``/diagnostics`` period, for the window since the last report: the achieved
rate (Hz), the share of sample periods it did not act on (1) and the p50/p99 latency (s)
from the sample to its output (the plant: from publishing a sample to the drive that
answers it, the loop's sample-to-drive latency). No allocation per sample: a preallocated
buffer and a few integers (the 1 kHz loop's budget is tens of microseconds per node).

The reports themselves (and other periodic housekeeping) run in the slack of a cycle
(:class:`Slack`), and the plant's run-wide latency percentiles come from a bounded
histogram (:class:`LatencyHistogram`), so a report runs where the period has room.
"""

import collections
import math
import time

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
        self.k_first = None         # first and last sample index acted on in this one
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
            if self.k_first is None:
                self.k_first = index
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
            if n:
                # misses count from the sample after the last one of the window before
                # (or, after an idle window, from this window's first): a node that idles
                # (plant held, no setpoint) reports its rate, not misses
                if self.k_last is not None:
                    base = self.k_prev if self.k_prev is not None else self.k_first - 1
                    expected = self.k_last - base
                else:
                    expected = int(round(dt * self.rate_hz))
                out['cycle.missed_share'] = max(0.0, 1.0 - n / expected) \
                    if expected > 0 else 0.0
        if n:
            lat = self.lat[:min(n, self.lat.size)]
            p50, p99 = np.percentile(lat, (50, 99))
            out['cycle.latency_p50_s'] = float(p50)
            out['cycle.latency_p99_s'] = float(p99)
        self.k_prev = self.k_last if n else None
        self.k_first = None
        self.n = 0
        self.t0_ns = now_ns
        return out


def loop_summary(lat, periods, missed, skipped, samples, idle=0):
    """
    Return the realtime loop statistics of a run (the plant's, for the summary).

    :param lat: the sample-to-drive latencies since the statistics started, a
        :class:`LatencyHistogram`.
    :param periods: sample periods since the statistics started.
    :param missed: ticks with no new drive.
    :param skipped: periods skipped by late ticks.
    :param samples: samples published.
    :param idle: periods in which the loop was not meant to run (the driver held its
        output: inactive, disabled, tripped): neither counted nor missed.
    :returns: dict with ``samples``, ``periods`` (the counted ones: ``idle_periods`` not
        among them), ``latency_n``, ``missed_cycles`` (``missed_no_drive`` plus
        ``missed_late_tick``), ``missed_share`` (1, of the counted periods), and
        ``latency_p50_s``, ``latency_p99_s``, ``latency_max_s`` (s) when there is one.
    """
    total = missed + skipped
    periods = max(0, int(periods) - int(idle))
    out = {'samples': int(samples), 'periods': periods, 'idle_periods': int(idle),
           'latency_n': int(lat.n), 'missed_cycles': int(total),
           'missed_no_drive': int(missed), 'missed_late_tick': int(skipped),
           'missed_share': float(total) / periods if periods else 0.0}
    if lat.n:
        p50, p99 = lat.percentiles((50, 99))
        out.update(latency_p50_s=float(p50), latency_p99_s=float(p99),
                   latency_max_s=float(lat.max))
    return out


class Slack:
    """
    Run periodic housekeeping in the slack right after a control cycle, one job a cycle.

    A ``/diagnostics`` report costs 0.2-0.7 ms in a running graph (percentiles, message
    building); run from its own timer it ran back to back with another one or just
    before a tick, and every late tick of a traced 30 s composed run followed one (the
    :class:`~fiber_align.nodes.ros.bus.Pub` of a node's per-sample output calls
    :meth:`after_cycle` once the sample has been answered, with most of the period
    left). Without cycles (lockstep waits, an idle or held graph) a job runs at once.

    :param idle_s: a cycle older than this (s, monotonic) means no cycle is running.
    """

    def __init__(self, idle_s=0.05):
        """Start with no job and no cycle seen."""
        self.jobs = collections.deque()
        self.idle_s = float(idle_s)
        self.t_cycle = -math.inf
        #: True while one timer callback ticks several sample clocks (the rig's, the
        #: station's axes): a job waits for the end of the whole tick (:meth:`end_tick`),
        #: not for the first axis's answered sample, so it never delays the other axes
        self.in_tick = False

    def end_tick(self):
        """End a tick of several sample clocks: run the oldest waiting job, if any."""
        self.in_tick = False
        self.after_cycle()

    def submit(self, job):
        """Run ``job`` (a callable) after the next cycle, or now when no cycle runs."""
        if time.monotonic() - self.t_cycle > self.idle_s:
            while self.jobs:
                self.jobs.popleft()()
            job()
        elif job not in self.jobs:
            self.jobs.append(job)

    def after_cycle(self):
        """Note a finished cycle; run the oldest waiting job, if any (not mid-tick)."""
        self.t_cycle = time.monotonic()
        if self.jobs and not self.in_tick:
            self.jobs.popleft()()


class LatencyHistogram:
    """
    Run-wide latency percentiles in bounded memory and constant time per sample.

    Log-spaced bins 1 % wide from 0.1 us to 10 s: a percentile is the geometric centre
    of its bin, within 0.5 % of the value a sort of every sample would give (the plant
    kept every latency and sorted them all each report: 0.45 ms at 20 s of a run, and
    growing).
    """

    LO_S = 1e-7
    RATIO = 1.01

    def __init__(self, hi_s=10.0):
        """Start empty."""
        self._inv = 1.0 / math.log(self.RATIO)
        self.counts = [0] * (int(math.log(hi_s / self.LO_S) * self._inv) + 2)
        self.n = 0
        self.max = 0.0

    def record(self, x):
        """Count one latency ``x`` (s)."""
        i = int(math.log(x / self.LO_S) * self._inv) + 1 if x > self.LO_S else 0
        self.counts[min(i, len(self.counts) - 1)] += 1
        self.n += 1
        if x > self.max:
            self.max = x

    def percentiles(self, qs):
        """Return the latencies (s) at the percentiles ``qs`` (0..100), or ``None``."""
        if not self.n:
            return None
        cum = np.cumsum(self.counts)
        out = []
        for q in qs:
            i = int(np.searchsorted(cum, max(1.0, q / 100.0 * self.n)))
            out.append(min(self.max, self.LO_S * self.RATIO ** (i - 0.5)) if i else 0.0)
        return out


#: s: the cycle WARN follows the missed share of this recent window (:class:`RecentShare`)
RECENT_S = 10.0


class RecentShare:
    """
    The missed share of the recent window, from a run's cumulative counts (pure).

    A WARN on the run-wide share stayed for the rest of a run after one bad stretch (five
    driver cycles: 37 % missed, WARN to the end); the share of the last ``window_s``
    seconds clears once the loop is healthy again. The window reaches back to the
    newest report at least ``window_s`` old (so it spans ``window_s`` plus at most one
    report period); statistics that restart (counts going down) start it again.

    :param window_s: the window (s).
    """

    def __init__(self, window_s=RECENT_S):
        """Start with no report."""
        self.window_s = float(window_s)
        self.points = collections.deque()

    def update(self, t_s, periods, missed):
        """
        Take the run's counts at ``t_s`` (monotonic s); return the window's figures.

        :param periods: periods counted since the statistics started; :param missed:
            those missed (:func:`loop_summary`'s ``periods``, ``missed_cycles``).
        :returns: dict: ``periods``, ``missed``, ``missed_share`` (1), ``seconds`` (s)
            of the window.
        """
        pts = self.points
        if pts and (periods < pts[-1][1] or missed < pts[-1][2]):
            pts.clear()
        pts.append((float(t_s), int(periods), int(missed)))
        while len(pts) > 1 and pts[-1][0] - pts[1][0] >= self.window_s:
            pts.popleft()
        t0, p0, m0 = pts[0]
        dp, dm = int(periods) - p0, int(missed) - m0
        return {'periods': dp, 'missed': dm, 'missed_share': dm / dp if dp else 0.0,
                'seconds': float(t_s) - t0}


def cycle_warning(figures, goal_share):
    """
    Return the WARN text of a loop that missed more than ``goal_share`` of its periods.

    :param figures: :meth:`RecentShare.update`'s dict (``missed_share``, ``periods``,
        ``seconds``: the recent window), or :func:`loop_summary`'s (the whole run).
    :param goal_share: the share allowed (1); <= 0: never a warning.
    :returns: the text, or ``None`` (within the goal, or nothing counted yet).
    """
    share = figures.get('missed_share')
    if goal_share <= 0 or not figures.get('periods') or share is None or share <= goal_share:
        return None
    when = ('in the last %.0f s' % figures['seconds']) if 'seconds' in figures \
        else 'since the run started'
    return 'missed %.3g %% of the cycles %s (goal <= %.3g %%)' % (
        100 * share, when, 100 * goal_share)
