# SPDX-License-Identifier: Apache-2.0
"""
DDS publishes of a realtime process, made off its control thread (:class:`Sender`).

The control thread converts a message to its C structure and queues it; one thread of the
process calls ``rcl_publish`` by ``ctypes`` (the GIL released), so a publish that waits in
Fast DDS holds up nobody but that thread. The nodes' log lines (:class:`QueuedLogger`)
and the process's listing of the graph's topics (:meth:`Sender.watch_graph`) take the
same thread. Why, and what was measured: docs/realtime.md ("The fix: the control thread
does not call DDS").
"""

import collections
import ctypes
import sys
import threading
import time

from rclpy.logging import LoggingSeverity

from fiber_align.analysis.bag.packer import NUMBERS
from fiber_align.nodes.ros.rcl_ctypes import c_text, Location, MessageType, Rcl


def _at(severity):
    """Return the :class:`QueuedLogger` method that logs at ``severity``."""
    def log(self, message, **kwargs):
        return self._log(message, severity, kwargs)
    log.__doc__ = 'Log ``message`` at %s.' % severity.name
    return log


class QueuedLogger:
    """
    A node's rclpy logger whose lines the :class:`Sender` thread writes, in its order.

    The severity check and the caller's function, file and line are taken here (the
    control thread); ``rcutils_log`` (console and ``/rosout``) runs on the sender thread
    without the GIL. While the sender does not run, or for the ``once`` / ``throttle``
    keywords, the line goes to rclpy's logger at once. Everything else is rclpy's.
    """

    def __init__(self, logger, sender):
        """Wrap ``logger`` (an rclpy ``RcutilsLogger``) for ``sender``."""
        self._logger = logger
        self._sender = sender

    def __getattr__(self, name):
        """Return the wrapped logger's attribute (name, levels, children)."""
        return getattr(self._logger, name)

    def _log(self, message, severity, kwargs):
        s = self._sender
        if kwargs or not s.running:
            return self._logger.log(message, severity, **kwargs)
        if not self._logger.is_enabled_for(severity):
            return False
        f = sys._getframe(2)
        s.put_log(int(severity), self._logger.name, message, f.f_code.co_name,
                  f.f_code.co_filename, f.f_lineno)
        return True

    def log(self, message, severity, **kwargs):
        """Log ``message`` at ``severity`` (rclpy's ``LoggingSeverity``)."""
        return self._log(message, severity, kwargs)

    debug = _at(LoggingSeverity.DEBUG)
    info = _at(LoggingSeverity.INFO)
    warning = warn = _at(LoggingSeverity.WARN)
    error = _at(LoggingSeverity.ERROR)
    fatal = _at(LoggingSeverity.FATAL)


#: rclpy field types read and rebuilt whole (:meth:`Sender.keep`)
_PLAIN = frozenset(NUMBERS).union(('string',))


def _single_field(msg_type):
    """Return the field name of a message of one plain value, else None."""
    fields = msg_type.get_fields_and_field_types()
    if len(fields) == 1:
        (name, typ), = fields.items()
        if typ in _PLAIN:
            return name
    return None


class _Value:
    """The kept value of a one-field message (:meth:`Sender.keep`)."""

    __slots__ = ('value',)

    def __init__(self, value):
        self.value = value


class Writer:
    """
    One rclpy publisher as the control thread sees it: :meth:`publish` never waits on DDS.

    While its :class:`Sender` runs, a message is converted here and published by the
    sender's thread; otherwise (lockstep, no sender) rclpy publishes it at once. A
    volatile writer with no matched reader skips the message (the count is refreshed every
    :attr:`Sender.refresh_s`); a durable one keeps its newest (a one-value message as the
    value) and the sender publishes it once a refresh, so a late reader gets the present.
    Why and what it saved: docs/realtime.md ("The fix: the control thread does not call DDS").
    """

    __slots__ = ('pub', 'volatile', 'readers', 'sender', 'ptr', 'ctype', 'pending', 'field')

    def __init__(self, pub, volatile, sender=None):
        """Wrap rclpy publisher ``pub``; ``volatile``: its durability is volatile."""
        self.pub = pub
        self.volatile = bool(volatile)
        self.sender = sender
        self.readers = 1
        self.ptr = pub.handle.pointer if sender is not None else None
        self.ctype = MessageType(pub.msg_type) if sender is not None else None
        self.pending = None     # durable, no reader: the newest C message, not yet sent
        #: the one field of a message of one plain value (kept as the value), or None
        self.field = _single_field(pub.msg_type)

    def publish(self, msg):
        """Publish ``msg`` (queued while the sender runs, else at once)."""
        s = self.sender
        if s is not None and s.running:
            if self.readers:
                s.put(self, msg)
            elif not self.volatile:
                s.keep(self, msg)
        elif not self.volatile or self.pub.get_subscription_count():
            self.pub.publish(msg)


class Sender:
    """
    The DDS publishes of one process, made in order by one thread of their own.

    Every :class:`Writer` of the sender goes through one FIFO, so the order of the
    messages across topics is the order they were published in. The queue holds at most
    ``max_queued`` messages; beyond that the oldest are dropped and counted
    (:attr:`dropped`, on each node's ``/diagnostics`` as ``sender.dropped``), never lost
    silently.

    :param refresh_s: how often the thread refreshes the matched-reader counts (s).
    """

    def __init__(self, max_queued=200000, refresh_s=0.01):
        """Create a stopped sender (:meth:`start` starts its thread)."""
        self._q = collections.deque()
        self._wake = threading.Event()
        self._thread = None
        self._stopping = False
        self._writers = []
        self._lock = threading.Lock()
        self._keep_lock = threading.Lock()     # Writer.pending only: never held over DDS
        self._rcl = None
        self.max_queued = int(max_queued)
        self.refresh_s = float(refresh_s)
        self.running = False
        self.published = 0
        self.failed = 0
        self.dropped = 0
        self.backlog_max = 0
        self.logged = 0
        self.error = ''
        self._graph_ptr = None      # the rcl node the graph is listed through
        self.graph_period_s = None  # s between listings (None: nobody asked)
        self._graph = None          # the newest listing: [(topic, [type, ...]), ...]
        self.graph_listings = 0

    def watch_graph(self, node, period_s):
        """
        List the graph's topics every ``period_s`` (s) on the sender thread.

        One listing serves every node of the process (they share one DDS participant,
        so one graph); the shortest period asked for wins. Read it with
        :meth:`graph_topics`.
        """
        with self._lock:
            if self._graph_ptr is None:
                self._graph_ptr = node.handle.pointer
            period_s = float(period_s)
            if self.graph_period_s is None or period_s < self.graph_period_s:
                self.graph_period_s = period_s

    def graph_topics(self):
        """Return the newest listing ``[(topic, [type, ...]), ...]``; ``None``: none yet."""
        return self._graph

    def queue_logs(self, node):
        """Let the sender thread write ``node``'s log lines (:class:`QueuedLogger`)."""
        if not isinstance(node._logger, QueuedLogger):
            node._logger = QueuedLogger(node._logger, self)

    def writer(self, pub, volatile):
        """Return the :class:`Writer` of rclpy publisher ``pub`` on this sender."""
        w = Writer(pub, volatile, self)
        self._writers.append(w)
        return w

    def forget(self, writer):
        """
        Detach ``writer`` before its publisher is destroyed.

        Its queued messages are dropped (counted); the thread holds :attr:`_lock` for the
        length of each publish, so none is in flight on return.
        """
        with self._lock:
            if writer in self._writers:
                self._writers.remove(writer)
            self._drop_pending(writer)
            if writer.ptr is not None and writer.sender is self:
                writer.sender = None
                writer.ptr = None

    def start(self):
        """
        Start the thread; from now on the writers queue their messages.

        :returns: True when it runs; False (messages stay on the caller's thread, the
            reason in :attr:`error`) when rcl could not be bound.
        """
        if self.running:
            return True
        try:
            self._rcl = Rcl()
        except (OSError, AttributeError) as exc:
            self.error = str(exc)
            return False
        self._refresh()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name='fiber_align.sender',
                                        daemon=True)
        self.running = True
        self._thread.start()
        return True

    def stop(self, timeout_s=2.0):
        """
        Publish what is queued, then stop the thread (at most ``timeout_s`` s).

        :returns: the number of messages still queued (0: everything went to DDS).
        """
        if not self.running:
            return len(self._q)
        self._stopping = True
        self._wake.set()
        self._thread.join(timeout_s)
        self.running = False
        self._graph = None
        # a thread still inside a publish: wait for it (bounded) and detach every writer,
        # so the publishers can be destroyed under it
        if self._lock.acquire(timeout=timeout_s):
            for w in self._writers:
                w.ptr = None
                self._drop_pending(w)
            self._writers = []
            self._graph_ptr = None
            self._lock.release()
        left = len(self._q)
        if not self._thread.is_alive():
            while self._q:
                w, msg = self._q.popleft()
                if w is not None:
                    w.ctype.destroy(msg)
        return left

    def put(self, writer, msg):
        """Convert ``msg`` for ``writer`` and queue it (the control thread's side)."""
        self._queue(writer, writer.ctype.to_c(msg))

    def put_log(self, severity, name, message, function, file, line):
        """Queue a log line: severity (rcutils), logger name, text, caller's place."""
        self._queue(None, (int(severity), c_text(name), c_text(message),
                           c_text(function), c_text(file), int(line)))

    def _queue(self, writer, item):
        q = self._q
        q.append((writer, item))
        n = len(q)
        if n > self.backlog_max:
            self.backlog_max = n
        if n > self.max_queued:
            try:
                w, ptr = q.popleft()
            except IndexError:       # the thread took it meanwhile
                pass
            else:
                if w is not None:
                    w.ctype.destroy(ptr)
                self.dropped += 1
        if not self._wake.is_set():
            self._wake.set()

    def keep(self, writer, msg):
        """Keep ``msg`` as ``writer``'s newest (durable, no reader yet): its value, or C."""
        if writer.field is not None:
            # one plain value: read at once (the node reuses its message), no conversion
            writer.pending = _Value(getattr(msg, writer.field))
            return
        ptr = writer.ctype.to_c(msg)
        with self._keep_lock:
            old, writer.pending = writer.pending, ptr
        if old is not None:
            writer.ctype.destroy(old)

    def _drop_pending(self, writer):
        with self._keep_lock:
            ptr, writer.pending = writer.pending, None
        if ptr is not None and not isinstance(ptr, _Value):
            writer.ctype.destroy(ptr)

    def _take_pending(self):
        """Queue the newest kept message of each durable writer (the sender thread)."""
        for w in list(self._writers):
            if w.pending is not None:
                with self._keep_lock:
                    ptr, w.pending = w.pending, None
                if isinstance(ptr, _Value):
                    ptr = w.ctype.to_c(w.pub.msg_type(**{w.field: ptr.value}))
                if ptr is not None:
                    self._q.append((w, ptr))

    def stats(self):
        """Return the sender's counters for ``/diagnostics`` (``sender.*`` keys)."""
        return {'sender.published': self.published, 'sender.dropped': self.dropped,
                'sender.failed': self.failed, 'sender.backlog_max': self.backlog_max}

    def _write_log(self, severity, name, message, function, file, line):
        loc = Location(function, file, line)
        self._rcl.log(ctypes.byref(loc), ctypes.c_int(severity), ctypes.c_char_p(name),
                      ctypes.c_char_p(b'%s'), ctypes.c_char_p(message))
        self.logged += 1

    def _refresh(self):
        n = ctypes.c_size_t()
        with self._lock:
            for w in self._writers:
                if self._rcl.count(w.ptr, ctypes.byref(n)) == 0:
                    w.readers = n.value

    def _list_graph(self):
        with self._lock:
            if self._graph_ptr is None:
                return
            listing = self._rcl.topic_names_and_types(self._graph_ptr)
        if listing is not None:
            self._graph = listing
            self.graph_listings += 1

    def _run(self):
        q, wake, rcl, lock = self._q, self._wake, self._rcl, self._lock
        t_refresh, t_graph = time.monotonic(), None
        while True:
            wake.wait(self.refresh_s)
            wake.clear()
            while q:
                w, msg = q.popleft()
                if w is None:
                    self._write_log(*msg)
                    continue
                with lock:
                    if w.ptr is None:
                        self.dropped += 1
                    elif rcl.publish(w.ptr, msg, None) == 0:
                        self.published += 1
                    else:
                        rcl.reset_error()
                        self.failed += 1
                w.ctype.destroy(msg)
            now = time.monotonic()
            if now - t_refresh >= self.refresh_s or self._stopping:
                t_refresh = now
                self._refresh()
                self._take_pending()
            if self.graph_period_s is not None and (t_graph is None or now - t_graph
                                                    >= self.graph_period_s):
                t_graph = now
                self._list_graph()
            if self._stopping and not q:
                return
