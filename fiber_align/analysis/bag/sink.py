# SPDX-License-Identifier: Apache-2.0
"""
Where a recorder's messages go: the bag, the flight recorder's rings, the counts (pure).

:class:`Sink` is the writing half of ``bag_recorder`` without ROS: a topic gets a
connection and a ``write(t_ns, data)`` (:meth:`Sink.put`) that keeps the message for the
flight recorder, writes it to the bag and counts it; a failed write (a full disk) is
``False`` and the bag is closed readable (:class:`~fiber_align.analysis.bag.guard.GuardedBag`).
With the full recording off the bag is a :class:`~fiber_align.analysis.bag.flight.NoBag`
and only the rings keep anything.
"""

import os
import time

from fiber_align.analysis.bag.common import storage_plugin, typestore as jazzy_typestore
from fiber_align.analysis.bag.flight import NoBag
from fiber_align.analysis.bag.guard import GuardedBag, write_json
from fiber_align.config import ConfigError


class Sink:
    """
    A recorder's bag, its counts and the flight recorder's keepers.

    :param bag: the bag (``GuardedBag`` or ``NoBag``): ``add_connection``, ``write``,
        ``flush``, ``close``, ``counts``, ``stopped``.
    :param typestore: the rosbags typestore (``Stores.ROS2_JAZZY``).
    :param keeper: ``(topic, msgtype) -> append(t_ns, data)`` or None: the flight
        recorder's ring of a topic.
    :param flush_s: s between chunk closes (:meth:`flush_due`); 0: never by time.
    """

    def __init__(self, bag, typestore, keeper, flush_s):
        """Keep the bag; no topic yet."""
        self.bag, self.typestore, self.keeper = bag, typestore, keeper
        self.flush_s = float(flush_s)
        self.counts = {}            # topic -> messages written
        self.closed = False
        self.t_flush = time.monotonic()

    @classmethod
    def open(cls, output, storage, keeper, flush_s):
        """
        Open the bag ``output`` (``''``: no bag, snapshots only) in ``storage``.

        :raises ConfigError: ``output`` exists already.
        """
        store = jazzy_typestore()
        if not output:
            return cls(NoBag(), store, keeper, flush_s)
        if os.path.exists(output):
            raise ConfigError('output %s exists already; choose a new bag directory'
                              % output)
        from rosbags.rosbag2 import Writer
        writer = Writer(output, version=9, storage_plugin=storage_plugin(storage))
        writer.open()
        return cls(GuardedBag(writer), store, keeper, flush_s)  # a full disk: closed readable

    def put(self, topic, msgtype):
        """
        Add ``topic`` and return its ``write(t_ns, data) -> bool`` (False: the write failed).

        :raises Exception: the type is unknown to the typestore.
        """
        conn = self.bag.add_connection(topic, msgtype, typestore=self.typestore)
        keep = self.keeper(topic, msgtype)
        write, counts = self.bag.write, self.counts
        counts[topic] = 0

        def put(t_ns, data):
            if self.closed:
                return True
            if keep is not None:
                keep(t_ns, data)
            if not write(conn, t_ns, data):
                return False
            counts[topic] += 1
            return True
        return put

    def flush_due(self):
        """Close the chunk when ``flush_s`` has passed; False: the flush failed."""
        now = time.monotonic()
        if self.flush_s > 0 and now - self.t_flush >= self.flush_s and not self.closed:
            self.t_flush = now
            return self.flush()
        return True

    def flush(self):
        """Write the pending chunk to the file; False: it failed (a full disk)."""
        return self.closed or self.bag.flush()

    def finish(self, output, counts_file, events):
        """
        Close the bag and write the counts files; return ``(info, warning)`` lines.

        :param counts_file: write ``recorder_counts.json`` and ``recorder_events.json``
            (``events``) next to a bag.
        """
        self.closed = True
        why = self.bag.close()
        if self.bag.stopped:
            self.counts.update(self.bag.counts())   # the bag's: a cut chunk is not in it
        msg = ', '.join('%s: %d' % kv for kv in sorted(self.counts.items())) or 'no topics'
        info = 'bag %s closed%s; messages per topic: %s' % (
            output or '(none: snapshots only)', (' (%s)' % why) if why else '', msg)
        why = counts_file and output and write_json(output, {
            'recorder_counts.json': self.counts, 'recorder_events.json': events})
        return info, ('no recorder_counts.json: %s' % why) if why else ''
