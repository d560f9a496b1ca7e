# SPDX-License-Identifier: Apache-2.0
"""
What ``bringup``'s observer records of a running graph, per sample: pure (no rclpy).

The streams it is given (one value per message, SI) and, with a ``clock`` stream (the
1-D ``displacement``), the sample times and the scenario's reference at each
(:class:`~fiber_align.simulation.setpoints.Source`); the ``alignment_state`` statuses
with the sample index from which each holds; the scenario runner's ``done``. The
counting rules live here, unit-tested without ROS;
:class:`fiber_align.bringup.observer.Observer` feeds it from its subscriptions (its
executor's thread: every access holds :attr:`RunRecord.lock`). Beside it, the nodes'
``/diagnostics`` (:class:`DiagnosticsRecord`).
"""

import json
import math
import threading
import time

import numpy as np

from fiber_align.analysis.bag.common import BagError
from fiber_align.analysis.bag.reader import BagReader
from fiber_align.analysis.recording import diag_entry
from fiber_align.analysis.run_summary import worst_cycles

#: s: the longest diagnostics period of a node of the graph (fiber_align.yaml: 0.5 s),
#: plus margin: the first report counted starts its window inside the run.
WINDOW_S = 0.6


class RunRecord:
    """
    The per-sample record of one run.

    :param streams: the keys of the streams recorded per message.
    :param clock: the key of the stream that times the samples (``None``: none).
    :param source: the scenario's Source (the trace's reference) or ``None``.
    :param lockstep: sample times are multiples of ``1 / rate_hz``.
    :param duration_s: the run ends at this sample time (s).
    """

    def __init__(self, streams, clock=None, source=None, lockstep=False, rate_hz=1000.0,
                 duration_s=math.inf):
        """Start an empty record (recording from :attr:`active`)."""
        self.source, self.lockstep, self.clock = source, lockstep, clock
        self.period, self.duration = 1.0 / rate_hz, float(duration_s)
        self.lock = threading.Lock()
        self.data = {k: [] for k in streams}
        self.stamps = {k: [] for k in streams}      # monotonic s of each message
        self.t, self.r = [], []
        self.states = []             # (sample index, status dict) of alignment_state
        self.active = clock is None  # record samples (the clock stream: from start())
        self.t0_ns = None
        self.done = threading.Event()
        self.progress = self.started = time.monotonic()
        #: monotonic s at which the scenario runner said ``done`` (``None``: not yet)
        self.runner_done_at = None

    @property
    def samples(self):
        """Return the samples recorded in every stream (the clock's count, if any)."""
        with self.lock:
            if self.clock is not None:
                return len(self.t)
            return min((len(v) for v in self.data.values()), default=0)

    def add(self, key, value, stamp_ns=None):
        """Record ``value`` (SI) of stream ``key``; the clock's with its stamp (ns)."""
        if key == self.clock:
            return self._add_sample(stamp_ns, value)
        if self.active or self.data[key]:
            with self.lock:
                self.data[key].append(value)
                self.stamps[key].append(time.monotonic())

    def _add_sample(self, ns, y):
        if not self.active or self.done.is_set():
            return
        self.t0_ns = ns if self.t0_ns is None else self.t0_ns
        t = (ns - self.t0_ns) * 1e-9
        if self.lockstep:
            t = round(t / self.period) * self.period
        if t >= self.duration - 0.5 * self.period:
            self.done.set()
            return
        self.progress = time.monotonic()
        with self.lock:
            self.t.append(t)
            self.data[self.clock].append(y)
            if self.source is not None:
                self.r.append(math.nan if self.source.open_loop else self.source.value(t))

    def runner_state(self, text):
        """Note the scenario runner's state (``scenario_state``): the time of ``done``."""
        if text == 'done' and self.runner_done_at is None:
            self.runner_done_at = time.monotonic()

    def behind(self, drain_s):
        """
        Return True when the runner's ``done`` is ``drain_s`` (s) old and this record short.

        Short: this record's own sample clock has not reached the end. Realtime only:
        on a loaded machine the observer reads the 1 kHz streams slower than the graph
        sends them, and would end the run long after the graph's end.
        """
        return (not self.lockstep and self.runner_done_at is not None
                and not self.done.is_set()
                and time.monotonic() - self.runner_done_at > drain_s)

    def add_state(self, text):
        """Record an ``alignment_state`` message (JSON status, or a bare state name)."""
        try:
            st = json.loads(text)
        except ValueError:
            st = {'state': text}
        with self.lock:
            self.states.append((self._state_index(st), st))

    def _state_index(self, st):
        """
        Return the sample index from which state ``st`` holds.

        Lockstep with a clock: the sample after the one the sequencer stepped last (its
        stamp in ``sample_time_s``); the observer may be behind the graph. Otherwise the
        state's own ``sample``, or the samples received so far.
        """
        ts = st.get('sample_time_s')
        if self.lockstep and ts is not None and self.t0_ns is not None:
            return int(round((float(ts) - self.t0_ns * 1e-9) / self.period)) + 1
        return st['sample'] if self.clock is None and 'sample' in st else len(self.t)

    def caused(self, n_before, command='', timeout_s=5.0):
        """
        Return the sample index of the state a command caused: the next after ``n_before``.

        Waits for it (bounded, s wall; none: the samples so far). Lockstep ``align``: the
        sequencer's own count (the status's ``align_sample``) is the truth.
        """
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.lock:
                if len(self.states) > n_before:
                    k, st = self.states[n_before]
                    own = st.get('align_sample') if self.lockstep and command == 'align' \
                        else None
                    return k if own is None else int(own)
            time.sleep(0.002)
        return self.samples

    @property
    def status(self):
        """Return the latest ``alignment_state`` status dict (``{}`` before the first)."""
        with self.lock:
            return dict(self.states[-1][1]) if self.states else {}

    def first(self, state, after=-1):
        """Return ``(index, status)`` of the first ``state`` from index ``after`` on."""
        with self.lock:
            return next(((k, dict(s)) for k, s in self.states
                         if s.get('state') == state and k >= after), (None, None))

    def trace(self):
        """Return ``(t, r, y)`` arrays (s, m, m) of the clock's samples (r NaN if unknown)."""
        return np.array(self.t), self.series('r'), self.series(self.clock)

    def series(self, key):
        """Return a stream (or ``r``) per sample, cut or padded with NaN to the samples."""
        with self.lock:
            n = len(self.t) if self.clock is not None else \
                min((len(v) for v in self.data.values()), default=0)
            src = self.r if key == 'r' else self.data[key]
            out = np.full(n, np.nan)
            m = min(n, len(src))
            out[:m] = src[:m]
            return out

    def columns(self, keys):
        """Return ``{key: series}`` of every stream in ``keys`` (:meth:`series`, SI)."""
        return {k: self.series(k) for k in keys}


def record_from_bag(path, source, rate_hz, duration_s):
    """
    Return ``(record, error)`` of a recorded 1-D run, read from its bag after the stop.

    The :class:`RunRecord` as the observer would have recorded it: ``y``, the
    ``displacement`` samples (their stamps time them) below ``duration_s`` (s); ``v``, the
    ``drive_voltage`` (V) from the first sample on. ``error``: why an unreadable bag gave
    an empty record (``''``: none).
    """
    rec = RunRecord(('y', 'v'), 'y', source, False, rate_hz, duration_s)
    rec.active = True
    try:
        with BagReader(path) as bag:
            y, v = bag.read('displacement'), bag.read('drive_voltage')
    except BagError as exc:
        return rec, str(exc)
    for ns, pos in zip(y.fields['stamp_ns'].tolist() if y else (),
                       y.fields['position'].tolist() if y else ()):
        rec.add('y', pos, ns)
    if y and v is not None:
        for val in v.fields['data'][v.t_ns >= y.t_ns[0]].tolist():
            rec.add('v', val)
    return rec, ''


class DiagnosticsRecord:
    """
    The newest ``/diagnostics`` values of every node, its worst cycle window, its errors.

    :ivar latest: node name -> its last key/value pairs (strings), ``level``, ``message``
        and ``_t`` (monotonic s of arrival).
    :ivar worst: node name -> its worst cycle window
        (:func:`~fiber_align.analysis.run_summary.worst_cycles`) among the reports of
        windows inside [:attr:`run_from`, :attr:`run_to`] (monotonic s).
    :ivar by_status: the same as ``latest`` and ``worst``, keyed by the full status name
        (``/rig/x/simulated_actuator``): the rig's axes have nodes of one base name.
    :ivar errors: node name -> the distinct ERROR messages it reported (why a FAULT).
    """

    def __init__(self):
        """Start with no report and no run."""
        self.latest, self.worst, self.errors = {}, {}, {}
        self.by_status = {'latest': {}, 'worst': {}}
        self.run_from = self.run_to = None

    def level(self, node):
        """Return the newest level of ``node`` (0 OK .. 3 STALE; ``None`` before any)."""
        return self.latest.get(node, {}).get('level')

    def add(self, status, now):
        """Fold in one ``diagnostic_msgs/DiagnosticStatus`` arrived at ``now`` (monotonic s)."""
        node, values = diag_entry(status, now)
        self.latest[node] = values
        self.by_status['latest'][status.name] = values
        if values['level'] >= 2 and values['message'] not in self.errors.get(node, []):
            self.errors.setdefault(node, []).append(values['message'])
        # a report covers the diagnostics period before it (0.5 s by default): the first
        # full window starts a period after the run did
        if self.run_from is not None and now >= self.run_from + WINDOW_S and (
                self.run_to is None or now <= self.run_to):
            worst_cycles(self.worst, node, values)
            worst_cycles(self.by_status['worst'], status.name, values)
