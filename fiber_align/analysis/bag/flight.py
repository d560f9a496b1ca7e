# SPDX-License-Identifier: Apache-2.0
"""
The flight recorder's pure core (no rclpy): the last seconds of every topic, cut on a trigger.

Every recorded topic keeps a :class:`Ring` of ``(receive time ns, CDR bytes)`` in memory,
also when the full recording is off. A ring is bounded twice: by time (the newest
``before_s + after_s + HORIZON_SLACK_S`` s) and by bytes (``max_bytes / n_topics`` per
topic, counting each message as its CDR bytes plus :data:`ENTRY_OVERHEAD_BYTES`, what
Python holds per kept message beside them): the memory of all rings is at most
``max_bytes``; while a snapshot is written its cut (a copy of at most the rings' content)
comes on top, so the peak is at most twice ``max_bytes``.

A trigger at wall time ``t`` (ns) asks for a :class:`Snapshot` of the window ``[t -
before_s, t + after_s]``: once ``after_s`` (and :data:`SETTLE_S`) has passed, a worker
thread (never the caller's: a composed recorder's callbacks run on a control thread) cuts
the window out of every ring and writes it as a rosbag2 bag (the recorder's storage,
through :class:`~fiber_align.analysis.bag.guard.GuardedBag`) into
``<folder>/<YYYYmmdd_HHMMSS>_<reason>/`` (local time of ``t``), with ``snapshot.json``
(reason, window, counts, the triggers it absorbed) beside the bag's files; ``fiber-align
analyze`` reads it as any recorded bag. Triggers are debounced: one inside the window of
the pending or last snapshot (``t <= its end``) makes none, it is counted
(:attr:`FlightRecorder.absorbed`) and named in that snapshot's ``snapshot.json``.

:class:`Triggers` turns what the recorder hears into reasons: the sequencer's
``alignment_state`` entering FAULT or HELD, a driver's ``watchdog_count`` rising, a
plant's cycle WARN (its loop missed more than its cycle goal), a driver's lifecycle
transition from active to inactive; the ``~/snapshot`` service is the reason ``service``.
"""

from collections import deque
from datetime import datetime
import heapq
import json
import os
import queue
import re
import threading
import time

from fiber_align.analysis.bag.common import storage_plugin, typestore
from fiber_align.analysis.bag.guard import GuardedBag, write_json
from fiber_align.analysis.recording import diag_entry

#: bytes of Python memory per kept message beside its CDR bytes: the ring's tuple (56),
#: the receive time's int (32), the bytes object's header (33), the deque's slot (8),
#: rounded up (``sys.getsizeof`` on CPython 3.12, 64 bit)
ENTRY_OVERHEAD_BYTES = 136
#: s a ring keeps beyond ``before_s + after_s``: the cut happens a little after the end
HORIZON_SLACK_S = 1.0
#: s waited after a window's end before it is cut (messages of its last moments taken)
SETTLE_S = 0.1
#: the sequencer states that trigger a snapshot (``alignment_state``'s ``state``)
STATES = ('FAULT', 'HELD')
#: the text of a plant's cycle WARN (:func:`fiber_align.control.cycle.cycle_warning`)
CYCLE_WARNING = 'of the cycles'
#: diagnostic_msgs levels
_WARN = 1
_SLUG = re.compile(r'[^a-z0-9]+')


def slug(reason, limit=40):
    """Return ``reason`` as a folder-name part: lower case, ``-`` between words."""
    return _SLUG.sub('-', str(reason).lower()).strip('-')[:limit].strip('-') or 'trigger'


def snapshot_name(t_ns, reason):
    """Return the folder name of a snapshot: ``<YYYYmmdd_HHMMSS>_<reason slug>`` (local)."""
    return '%s_%s' % (datetime.fromtimestamp(t_ns / 1e9).strftime('%Y%m%d_%H%M%S'),
                      slug(reason))


def free_path(folder, name, taken=()):
    """Return ``folder/name``, or with ``_2``, ``_3``, ... when it exists or is ``taken``."""
    path, n = os.path.join(folder, name), 1
    while os.path.exists(path) or path in taken:
        n += 1
        path = os.path.join(folder, '%s_%d' % (name, n))
    return path


class Ring:
    """
    One topic's last messages, ``(receive time ns, CDR bytes)``, bounded by time and bytes.

    :param horizon_s: s kept behind the newest message.
    :param max_bytes: bytes kept at most (CDR bytes + :data:`ENTRY_OVERHEAD_BYTES` each).
    """

    def __init__(self, horizon_s, max_bytes):
        """Start empty."""
        self.horizon_ns = int(horizon_s * 1e9)
        self.max_bytes = int(max_bytes)
        self.entries = deque()
        self.bytes = 0
        #: messages dropped for the byte cap before their time was out
        self.capped = 0
        self.lock = threading.Lock()

    def append(self, t_ns, data):
        """Keep one message (receive time ns, CDR bytes); drop what is out of bounds."""
        with self.lock:
            e = self.entries
            e.append((t_ns, data))
            self.bytes += len(data) + ENTRY_OVERHEAD_BYTES
            old = t_ns - self.horizon_ns
            while e and (e[0][0] < old or self.bytes > self.max_bytes):
                t, d = e.popleft()
                self.bytes -= len(d) + ENTRY_OVERHEAD_BYTES
                if t >= old:
                    self.capped += 1

    def cut(self, lo_ns, hi_ns):
        """Return the messages received in ``[lo_ns, hi_ns]`` (a list, oldest first)."""
        with self.lock:
            items = list(self.entries)
        return [x for x in items if lo_ns <= x[0] <= hi_ns]


class Snapshot:
    """
    One asked-for snapshot: its reason, trigger time and window (ns), its folder.

    :ivar path: the bag folder (set when asked: the name is the trigger's).
    :ivar absorbed: the reasons of the triggers inside its window (debounced).
    :ivar counts: ``{topic: messages written}`` once written; :ivar error: why not.
    """

    def __init__(self, reason, t_ns, before_s, after_s, path):
        """Ask for the window ``[t_ns - before_s, t_ns + after_s]`` (ns, s)."""
        self.reason, self.t_ns, self.path = str(reason), int(t_ns), path
        self.lo_ns = self.t_ns - int(before_s * 1e9)
        self.hi_ns = self.t_ns + int(after_s * 1e9)
        self.absorbed, self.counts, self.error = [], {}, None
        self.done = threading.Event()

    def info(self):
        """Return ``snapshot.json``'s content (times in s since the epoch, wall clock)."""
        return dict(reason=self.reason, trigger_time_s=self.t_ns / 1e9,
                    window_start_s=self.lo_ns / 1e9, window_end_s=self.hi_ns / 1e9,
                    absorbed_triggers=list(self.absorbed), messages=dict(self.counts),
                    error=self.error)


class FlightRecorder:
    """
    The rings of every topic, the snapshots asked for and their writer thread.

    :param folder: where snapshot folders are created (made if missing).
    :param before_s: s of a snapshot before its trigger; :param after_s: s after it.
    :param max_bytes: bytes all rings keep at most, split evenly over ``n_topics``.
    :param n_topics: the topics that will be kept (the recorder's wanted topics).
    :param storage: the bags' storage (``mcap`` or ``sqlite3``).
    :param on_written: called with each finished :class:`Snapshot` (worker thread).
    :param clock: wall time in ns (the rings' receive times' clock).
    :param thread: write in the worker thread (False: the snapshots wait in
        :attr:`queue` for the caller's :meth:`write`; the tests').
    """

    def __init__(self, folder, before_s, after_s, max_bytes, n_topics, storage='mcap',
                 on_written=None, clock=time.time_ns, thread=True):
        """Start with no ring; the worker thread starts with the first snapshot."""
        self.folder = os.path.abspath(folder)
        self.before_s, self.after_s = float(before_s), float(after_s)
        self.max_bytes = int(max_bytes)
        self.topic_bytes = self.max_bytes // max(1, int(n_topics))
        self.horizon_s = self.before_s + self.after_s + HORIZON_SLACK_S
        self.storage, self.on_written, self.clock = storage, on_written, clock
        self.rings = {}                 # topic -> (Ring, msgtype)
        self.snapshots = []             # every one asked for, in order
        self.absorbed = 0
        self.last_end_ns = None
        self.queue = queue.Queue()
        self.stop = threading.Event()
        self.worker, self.thread, self.closed = None, bool(thread), False

    # -- keeping ----------------------------------------------------------------------
    def ring(self, topic, msgtype):
        """Return the ring of ``topic`` (made on the first call); append to it."""
        if topic not in self.rings:
            self.rings[topic] = (Ring(self.horizon_s, self.topic_bytes), msgtype)
        return self.rings[topic][0]

    def memory(self):
        """Return ``(bytes kept in all rings, their bound)``."""
        return sum(r.bytes for r, _ in self.rings.values()), self.max_bytes

    # -- triggers ---------------------------------------------------------------------
    def trigger(self, reason, t_ns=None):
        """
        Ask for a snapshot around ``t_ns`` (ns, default now); return it, or None if debounced.

        A trigger inside the window of the pending or last snapshot makes none: it is
        counted and added to that snapshot's ``absorbed`` list.
        """
        t_ns = self.clock() if t_ns is None else int(t_ns)
        if self.closed:
            return None
        if self.last_end_ns is not None and t_ns <= self.last_end_ns:
            self.absorbed += 1
            self.snapshots[-1].absorbed.append(str(reason))
            return None
        # a snapshot not yet written has no folder yet: its name is taken all the same
        snap = Snapshot(reason, t_ns, self.before_s, self.after_s, free_path(
            self.folder, snapshot_name(t_ns, reason), {s.path for s in self.snapshots}))
        self.snapshots.append(snap)
        self.last_end_ns = snap.hi_ns
        if self.worker is None and self.thread:
            self.worker = threading.Thread(target=self._work, name='flight_recorder',
                                           daemon=True)
            self.worker.start()
        self.queue.put(snap)
        return snap

    def pending(self):
        """Return the snapshots asked for and not written yet."""
        return [s for s in self.snapshots if not s.done.is_set()]

    # -- writing (the worker thread) --------------------------------------------------
    def _work(self):
        while True:
            snap = self.queue.get()
            if snap is None:
                return
            wait_s = (snap.hi_ns - self.clock()) / 1e9 + SETTLE_S
            if wait_s > 0:
                self.stop.wait(wait_s)      # a stop: what there is now is written at once
            self.write(snap)

    def cut(self, snap):
        """Return ``{topic: (msgtype, [(t_ns, bytes), ...])}`` of the snapshot's window."""
        out = {}
        for topic, (ring, msgtype) in list(self.rings.items()):
            out[topic] = (msgtype, ring.cut(snap.lo_ns, snap.hi_ns))
        return out

    def write(self, snap):
        """Cut and write ``snap``'s bag and ``snapshot.json``; then :attr:`on_written`."""
        try:
            snap.counts = write_snapshot(snap.path, self.cut(snap), self.storage)
            why = write_json(snap.path, {'snapshot.json': snap.info()})
            snap.error = why
        except Exception as exc:  # noqa: BLE001 - the graph runs on; the reason is kept
            snap.error = '%s: %s' % (type(exc).__name__, exc)
        snap.done.set()
        if self.on_written is not None:
            self.on_written(snap)

    def close(self, timeout_s=5.0):
        """Write the pending snapshots with what the rings hold now (bounded); stop."""
        self.closed = True
        self.stop.set()
        if self.worker is not None:
            self.queue.put(None)
            self.worker.join(timeout_s)
        return self.snapshots

    def state(self):
        """Return the figures for ``/diagnostics`` (bytes, counts, the last snapshot)."""
        kept, bound = self.memory()
        done = [s for s in self.snapshots if s.done.is_set()]
        return {'snapshot_bytes': kept, 'snapshot_max_bytes': bound,
                'snapshot_topic_max_bytes': self.topic_bytes,
                'snapshots_written': sum(1 for s in done if not s.error),
                'snapshots_failed': sum(1 for s in done if s.error),
                'snapshots_pending': len(self.snapshots) - len(done),
                'snapshot_triggers_absorbed': self.absorbed,
                'snapshot_capped': sum(r.capped for r, _ in self.rings.values()),
                'snapshot_last': done[-1].path if done else ''}


def write_snapshot(path, cuts, storage='mcap'):
    """
    Write ``cuts`` (``{topic: (msgtype, [(t_ns, CDR bytes), ...])}``) as a new bag.

    :param path: the bag folder (must not exist; its parent is made).
    :returns: ``{topic: messages written}``.
    """
    from rosbags.rosbag2 import Writer
    os.makedirs(os.path.dirname(path), exist_ok=True)
    writer = Writer(path, version=9, storage_plugin=storage_plugin(storage))
    writer.open()
    bag = GuardedBag(writer)
    ts = typestore()
    counts = {}
    try:
        conns = {topic: bag.add_connection(topic, msgtype, typestore=ts)
                 for topic, (msgtype, _) in sorted(cuts.items())}
        counts = {topic: 0 for topic in conns}
        # in time order, as a recording: a chunk holding one topic's tail and the next
        # one's head starts at the head's time, and readers that take the chunks in time
        # order (this package's own, analysis/bag/reader.py) read the first topic's
        # messages out of order
        merged = heapq.merge(*[[(t_ns, topic, data) for t_ns, data in items]
                               for topic, (_, items) in sorted(cuts.items())],
                             key=lambda x: (x[0], x[1]))
        for t_ns, topic, data in merged:
            if not bag.write(conns[topic], t_ns, data):
                break
            counts[topic] += 1
    finally:
        why = bag.close()
    if bag.stopped or why:
        raise OSError(bag.stopped or why)
    return counts


class Triggers:
    """
    The reasons for a snapshot in what the recorder hears (pure; edges, not levels).

    Each method returns a reason (text) or None: a sequencer status entering a state of
    :data:`STATES`, a status whose ``watchdog_count`` rose, a plant status that turns to a
    cycle WARN, a lifecycle transition from ``active`` to ``inactive``.
    """

    def __init__(self):
        """Nothing seen yet: the first of each status is its baseline."""
        self.state = None
        self.watchdog = {}
        self.warned = {}

    def on_state(self, text):
        """Take one ``alignment_state`` (JSON text)."""
        try:
            state = json.loads(text).get('state')
        except (ValueError, AttributeError):
            return None
        before, self.state = self.state, state
        if state in STATES and state != before:
            return 'sequencer %s' % state
        return None

    def on_status(self, name, level, message, values):
        """Take one ``/diagnostics`` status (``values``: ``{key: text}``)."""
        out = None
        if 'watchdog_count' in values:
            try:
                n = int(values['watchdog_count'])
            except ValueError:
                n = None
            before = self.watchdog.get(name)
            if n is not None:
                self.watchdog[name] = n
                if before is not None and n > before:
                    out = 'watchdog %s' % name.rsplit('/', 1)[-1]
        if 'sim_time_s' in values:
            warned = level >= _WARN and CYCLE_WARNING in str(message)
            if warned and not self.warned.get(name):
                out = out or 'missed cycles %s' % name.rsplit('/', 1)[-1]
            self.warned[name] = warned
        return out

    def on_diagnostic(self, status):
        """Take one ``diagnostic_msgs/DiagnosticStatus`` (its level bytes or int)."""
        _, vals = diag_entry(status, 0.0)
        return self.on_status(status.name, vals['level'], vals['message'], vals)

    def on_transition(self, node, start_label, goal_label):
        """
        Take one lifecycle transition event of ``node`` (its states' labels).

        rcl publishes a deactivation as ``active`` -> ``deactivating``, then
        ``deactivating`` -> ``inactive``: the first is the trigger (one per deactivation).
        """
        if start_label == 'active' and goal_label in ('deactivating', 'inactive'):
            return '%s inactive' % node
        return None


class NoBag:
    """The bag of a recorder whose full recording is off: every write taken, none kept."""

    stopped = None

    def add_connection(self, *args, **kwargs):
        """Return no connection."""
        return None

    def write(self, conn, t_ns, data):
        """Take the message (nothing is written)."""
        return True

    def flush(self):
        """Nothing to flush."""
        return True

    def close(self):
        """Nothing to close; no reason."""
        return None

    def counts(self):
        """Return no counts."""
        return {}
