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


def test_its_own_message_records_make_the_file_the_writer_makes(tmp_path):
    """
    The records GuardedBag packs itself equal the rosbags writer's, byte for byte.

    Three topics, out-of-order stamps, more than a chunk (1 MiB) of messages and a flush
    between: the two mcap files and their metadata are the same.
    """
    ts = typestore()
    files = []
    for name, guarded in (('theirs', False), ('ours', True)):
        # the same bag name in both (the mcap's own metadata carries it)
        (tmp_path / name).mkdir()
        w = _open(tmp_path / name / 'bag')
        bag = GuardedBag(w) if guarded else w
        conns = [bag.add_connection(t, 'std_msgs/msg/String', typestore=ts)
                 for t in ('/a', '/b', '/c')]
        for i in range(1500):
            t_ns = 1_000_000_000 + 1000 * i - (5000 if i % 7 == 3 else 0)
            bag.write(conns[i % 3], t_ns, _message(ts, i))
            if i == 700:
                bag.flush() if guarded else w.storage.close_chunk()
        if guarded:
            assert bag._pack and bag.close() is None
        else:
            w.close()
        files.append(tmp_path / name / 'bag')
    (ours_mcap,) = files[1].glob('*.mcap')
    (theirs_mcap,) = files[0].glob('*.mcap')
    assert ours_mcap.read_bytes() == theirs_mcap.read_bytes()
    assert (files[1] / 'metadata.yaml').read_text() == (
        files[0] / 'metadata.yaml').read_text()
    with Reader(files[1]) as r:
        assert r.message_count == 1500
