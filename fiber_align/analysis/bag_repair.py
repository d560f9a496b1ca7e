# SPDX-License-Identifier: Apache-2.0
"""
Repair an MCAP bag whose recorder was killed: ``fiber-align bag-repair BAG``.

A recorder killed with SIGKILL (or a power cut) leaves ``BAG/BAG.mcap`` without its
summary and footer and ``BAG`` without ``metadata.yaml``: no reader opens it. The
recorder closes and writes its pending chunk every ``flush_period_s`` (0.01 s), so the
file holds every message up to then in complete chunks. This module scans the file's
records from the start (the MCAP format: magic, then opcode u8, length u64, content),
takes the schemas, channels and messages of every complete record, chunked or not, and
stops at the first record the kill cut short. It then writes them as a new, finalised
bag (rosbags, ``Stores.ROS2_JAZZY`` types) next to the old one, which is left as it was.
"""

from dataclasses import dataclass, field
from pathlib import Path
import struct

from fiber_align.analysis.bag import typestore

MAGIC = b'\x89MCAP0\r\n'
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x03, 0x04, 0x05, 0x06


class RepairError(ValueError):
    """The bag cannot be repaired; the message says why."""


@dataclass
class Scan:
    """What a scan recovered: schemas, channels and messages (log time ns, raw CDR)."""

    schemas: dict = field(default_factory=dict)     # id -> (name, encoding, data bytes)
    channels: dict = field(default_factory=dict)    # id -> (schema id, topic, encoding)
    messages: list = field(default_factory=list)    # (channel id, log_time_ns, bytes)
    truncated_at: int = -1                          # byte offset of the cut, -1: none
    complete: bool = False                          # the footer was reached


class _Reader:
    def __init__(self, buf):
        self.buf, self.pos = buf, 0

    def take(self, n):
        if self.pos + n > len(self.buf):
            raise EOFError
        out = self.buf[self.pos:self.pos + n]
        self.pos += n
        return out

    def u16(self):
        return struct.unpack('<H', self.take(2))[0]

    def u32(self):
        return struct.unpack('<I', self.take(4))[0]

    def u64(self):
        return struct.unpack('<Q', self.take(8))[0]

    def string(self):
        return bytes(self.take(self.u32())).decode('utf-8')


def _record(scan, op, content, depth=0):
    r = _Reader(content)
    if op == OP_SCHEMA:
        sid = r.u16()
        name, enc = r.string(), r.string()
        scan.schemas[sid] = (name, enc, bytes(r.take(r.u32())))
    elif op == OP_CHANNEL:
        cid, sid = r.u16(), r.u16()
        topic, enc = r.string(), r.string()
        scan.channels[cid] = (sid, topic, enc)
    elif op == OP_MESSAGE:
        cid = r.u16()
        r.u32()                         # sequence
        log_time = r.u64()
        r.u64()                         # publish time
        scan.messages.append((cid, log_time, bytes(content[r.pos:])))
    elif op == OP_CHUNK and depth == 0:
        r.u64()
        r.u64()                         # start and end time
        size = r.u64()
        r.u32()                         # crc
        compression = r.string()
        data = r.take(r.u64())
        if compression == 'zstd':
            import zstandard
            data = zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size)
        elif compression:
            raise RepairError('chunk compression %r is not supported' % compression)
        _records(scan, memoryview(data), 0, depth + 1)


def _records(scan, buf, pos, depth=0):
    """Walk the records of ``buf`` from ``pos``; return the offset where they stop."""
    while pos + 9 <= len(buf):
        op = buf[pos]
        (length,) = struct.unpack_from('<Q', buf, pos + 1)
        end = pos + 9 + length
        if end > len(buf):
            return pos                  # the kill cut this record short
        if op == 0x02 and depth == 0:   # footer: the file is complete
            scan.complete = True
            return end
        try:
            _record(scan, op, buf[pos + 9:end], depth)
        except EOFError:
            return pos
        pos = end
    return pos


def scan_mcap(path):
    """
    Return a :class:`Scan` of the MCAP file at ``path``.

    :raises RepairError: the file does not start with the MCAP magic.
    """
    data = Path(path).read_bytes()
    if not data.startswith(MAGIC):
        raise RepairError('%s is not an MCAP file (no magic)' % path)
    scan = Scan()
    end = _records(scan, memoryview(data), len(MAGIC))
    if not scan.complete:
        scan.truncated_at = end
    return scan


def repair(bag, out=None):
    """
    Write the messages recoverable from ``bag`` as a new bag; return its path and counts.

    :param bag: a bag directory (with a ``*.mcap`` file) or an ``.mcap`` file.
    :param out: the new bag directory (default ``<bag>_repaired``; must not exist).
    :returns: ``(out path, {topic: messages}, truncated_at byte offset or -1)``.
    :raises RepairError: nothing to repair or nothing recoverable.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    bag = Path(bag)
    files = [bag] if bag.is_file() else sorted(bag.glob('*.mcap'))
    if not files:
        raise RepairError('%s holds no .mcap file (sqlite3 bags: sqlite recovers them '
                          'itself)' % bag)
    out = Path(out) if out else bag.with_name(bag.stem + '_repaired') if bag.is_file() \
        else bag.with_name(bag.name + '_repaired')
    if out.exists():
        raise RepairError('%s exists already; choose another --out' % out)
    scans = [scan_mcap(f) for f in files]
    if not any(s.messages for s in scans):
        raise RepairError('%s: no complete message to recover' % bag)
    ts = typestore()
    counts, conns = {}, {}
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        for s in scans:
            for cid, log_time, data in sorted(s.messages, key=lambda m: m[1]):
                sid, topic, _ = s.channels[cid]
                msgtype = s.schemas[sid][0]
                key = (topic, msgtype)
                if key not in conns:
                    conns[key] = writer.add_connection(topic, msgtype, typestore=ts)
                writer.write(conns[key], log_time, data)
                counts[topic] = counts.get(topic, 0) + 1
    finally:
        writer.close()
    return out, counts, scans[-1].truncated_at


def register(sub):
    """Add ``bag-repair`` to the ``fiber-align`` command line."""
    p = sub.add_parser('bag-repair', help='turn a bag whose recorder was killed into a '
                       'readable one', description=__doc__.strip().split('\n')[0])
    p.add_argument('bag', help='bag directory (or .mcap file)')
    p.add_argument('--out', default=None, help='new bag directory (default BAG_repaired)')
    # checked by fiber-align before run_cli (fiber_align.tools.paths)
    p.set_defaults(func=run_cli, paths={'BAG': 'in-any', '--out': 'new-dir'})


def run_cli(args):
    """Run ``fiber-align bag-repair``; return the exit code (2 on a bad bag)."""
    import sys
    try:
        out, counts, cut = repair(args.bag, args.out)
    except (RepairError, OSError) as exc:
        print('fiber-align bag-repair: error: %s' % exc, file=sys.stderr)
        return 2
    total = sum(counts.values())
    print('bag-repair: %d messages on %d topics written to %s%s'
          % (total, len(counts), out, '' if cut < 0 else
             ' (the original ends in a record cut short at byte %d)' % cut))
    for topic, n in sorted(counts.items()):
        print('  %s: %d' % (topic, n))
    return 0
