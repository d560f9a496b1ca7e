# SPDX-License-Identifier: Apache-2.0
"""
A bag recorded into a full filesystem is closed readable (issue 39.5).

Into a real 5 MB tmpfs (mounted here as root, unmounted after): messages are written
through :class:`fiber_align.analysis.bag.guard.GuardedBag` until the disk is full. The
write then says so once (False, and one line naming the full disk and the bag), the bag
has its ``metadata.yaml`` and reads without repair, every message it counts is in it, and
the reserve is gone. Without the guard the same writes raise ``[Errno 28]`` and leave a
bag without metadata (checked first, so this test fails where the guard is missing).
"""

import os
import shutil

import pytest
from rosbags.rosbag2 import Reader, Writer

from fiber_align.analysis.bag import BagReader, storage_plugin, typestore
from fiber_align.analysis.bag.guard import GuardedBag
from procs import tmpfs

FS_BYTES = 5 * 1024 * 1024
#: messages of 1 kB: a 5 MB disk is full after about 5000 (a bound of 100000 ends a bug)
PAYLOAD = 1024
BOUND = 100000


def _message(ts, i):
    msg = ts.types['std_msgs/msg/String'](data='%08d' % i + 'x' * (PAYLOAD - 8))
    return ts.serialize_cdr(msg, 'std_msgs/msg/String')


def _open(bag):
    w = Writer(bag, version=9, storage_plugin=storage_plugin('mcap'))
    w.open()
    return w


@pytest.mark.parametrize('flush_every', [0, 50])
def test_a_full_disk_stops_the_recording_and_leaves_a_readable_bag(tmp_path, flush_every):
    ts = typestore()
    with tmpfs(tmp_path / 'fs', FS_BYTES) as fs:
        raw = _open(fs / 'unguarded')
        conn = raw.add_connection('/x', 'std_msgs/msg/String', typestore=ts)
        with pytest.raises(OSError):            # today's recorder: a traceback, no metadata
            for i in range(BOUND):
                raw.write(conn, i, _message(ts, i))
        assert not (fs / 'unguarded' / 'metadata.yaml').exists()
        raw.abort()
        shutil.rmtree(fs / 'unguarded')

        bag = GuardedBag(_open(fs / 'bag'))
        conn = bag.add_connection('/x', 'std_msgs/msg/String', typestore=ts)
        written = 0
        for i in range(BOUND):
            if flush_every and i % flush_every == 0 and not bag.flush():
                break
            if not bag.write(conn, 1000 + i, _message(ts, i)):
                break
            written += 1
        assert bag.stopped is not None and written < BOUND
        assert 'the disk is full at %s' % (fs / 'bag') in bag.stopped, bag.stopped
        assert '\n' not in bag.stopped and 'filesystem %s' % fs in bag.stopped
        assert not bag.write(conn, 0, _message(ts, 0))          # recording stopped
        assert bag.close() is None                              # the caller closes it
        assert (fs / 'bag' / 'metadata.yaml').is_file()
        assert not (fs / 'bag' / '.reserve').exists()
        with Reader(fs / 'bag') as r:                           # no repair needed
            rows = [(c.topic, t) for c, t, _ in r.messages()]
            assert r.message_count == len(rows)
        kept = len(rows)
        # the tail is lost (at most one chunk of 1 MB), the rest is there, in order
        assert kept >= written - (1024 * 1024) // PAYLOAD - 1 and kept > 1000, \
            (kept, written)
        print('%d of %d messages kept: %s' % (kept, written, bag.stopped))
        assert [t for _, t in rows] == list(range(1000, 1000 + kept))
        assert 'keeps the %d message(s)' % kept in bag.stopped
        with BagReader(str(fs / 'bag')) as br:                  # the package's reader too
            assert '/x' in br.all_topics
        assert os.statvfs(str(fs)).f_bavail >= 0


def test_a_bag_closed_normally_leaves_no_reserve(tmp_path):
    ts = typestore()
    bag = GuardedBag(_open(tmp_path / 'bag'))
    conn = bag.add_connection('/x', 'std_msgs/msg/String', typestore=ts)
    for i in range(10):
        assert bag.write(conn, i, _message(ts, i))
    assert bag.flush() and bag.close() is None and bag.stopped is None
    names = sorted(p.name for p in (tmp_path / 'bag').iterdir())
    assert names == ['bag.mcap', 'metadata.yaml']
    with Reader(tmp_path / 'bag') as r:
        assert r.message_count == 10
