# SPDX-License-Identifier: Apache-2.0
"""
The realtime graph with and without the Foxglove live view, a client connected.

Each row is one ``bringup --scenario sine --sync realtime --duration S --record DIR``
(the graph of ``bench_graph``), alternately without and with ``--live``; with the view,
a WebSocket client in this process (the Foxglove protocol, ``foxglove.sdk.v1``)
subscribes to every channel the view advertises and reads them all for the whole run.
Per row: cycles kept, missed cycles, sample-to-drive latency p50/p99 (ms), tracking
RMS and its ratio to the mean of the runs without the view, watchdog trips, whether
the bag holds exactly what every publisher sent, CPU (s per s) and resident memory
(MB) per process, and the client's messages per second.

Usage: ``python -m bench.bench_live [--seconds 60] [--pairs 3] [--hogs 0] [--json FILE]``.
Goals (issue 23): with the view >= 99.9 % cycles, nothing lost in the bag, RMS within
1.1x of the runs without it.
"""

import argparse
import asyncio
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

from bench.bench_graph import BRINGUP, row
from fiber_align.hardware.process import stop_process

PROTOCOL = 'foxglove.sdk.v1'


def free_port():
    """Return a TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class Reader(threading.Thread):
    """A Foxglove client that subscribes to every channel and counts what it receives."""

    def __init__(self, port, done):
        """Connect to ``ws://127.0.0.1:port`` (retried) until ``done`` is set."""
        super().__init__(daemon=True)
        self.port, self.done = port, done
        self.messages = 0
        self.channels = 0
        self.connected_at = None

    def run(self):
        """Run the client's loop (its own asyncio loop)."""
        asyncio.run(self._main())

    async def _main(self):
        import websockets
        ws = None
        while ws is None and not self.done.is_set():
            try:
                ws = await websockets.connect('ws://127.0.0.1:%d' % self.port,
                                              subprotocols=[PROTOCOL], max_size=None)
            except OSError:
                await asyncio.sleep(0.2)
        if ws is None:
            return
        self.connected_at = time.monotonic()
        subscribed, next_id = set(), 1
        try:
            while not self.done.is_set():
                try:
                    frame = await asyncio.wait_for(ws.recv(), 0.2)
                except asyncio.TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    break
                if isinstance(frame, bytes):
                    if frame[:1] == b'\x01':
                        struct.unpack_from('<IQ', frame, 1)
                        self.messages += 1
                    continue
                msg = json.loads(frame)
                if msg.get('op') == 'advertise':
                    subs = []
                    for c in msg['channels']:
                        if c['id'] not in subscribed:
                            subscribed.add(c['id'])
                            subs.append({'id': next_id, 'channelId': c['id']})
                            next_id += 1
                    self.channels = len(subscribed)
                    if subs:
                        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
        finally:
            await ws.close()


def run_once(tmp, tag, seconds, live, hogs_note):
    """Run one bringup (with the view and a client when ``live``); return its row."""
    bag = os.path.join(tmp, tag + '_bag')
    summary = os.path.join(tmp, tag + '.json')
    cmd = BRINGUP + ['--scenario', 'sine', '--sync', 'realtime', '--duration', str(seconds),
                     '--quiet', '--summary', summary, '--record', bag]
    reader, done = None, threading.Event()
    if live:
        port = free_port()
        cmd += ['--live', '--live-port', str(port)]
        reader = Reader(port, done)
        reader.start()
    log = os.path.join(tmp, tag + '.log')
    with open(log, 'w', encoding='utf-8') as f:
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, text=True)
    try:
        proc.wait(timeout=120 + 3 * seconds)
    except subprocess.TimeoutExpired:
        stop_process(proc, grace_s=30.0)    # bringup stops its graph and summarises
    finally:
        done.set()
        if reader is not None:
            reader.join(5.0)
    with open(log, encoding='utf-8') as f:
        out = f.read()
    if os.path.isfile(summary):
        with open(summary, encoding='utf-8') as f:
            s = json.load(f)
    else:
        s = {'error': out[-500:]}
    if proc.returncode:
        s.setdefault('error', 'exit code %s: %s' % (proc.returncode, out[-300:]))
    r = row('%s%s' % ('with view + client' if live else 'without view', hogs_note), s,
            None, None)
    if reader is not None:
        alive = time.monotonic() - reader.connected_at if reader.connected_at else 0.0
        r['client'] = {'channels': reader.channels, 'messages': reader.messages,
                       'messages_per_s': reader.messages / alive if alive else None}
    return r


def table(rows):
    """Return the Markdown table of the rows, RMS against the runs without the view."""
    base = [r['rms_m'] for r in rows if 'client' not in r and r['rms_m']]
    base = sum(base) / len(base) if base else None

    def f(v, scale=1.0, fmt='%.3g'):
        return '-' if v is None else fmt % (v * scale)
    lines = ['| run | cycles kept | missed | latency p50 / p99 (ms) | RMS (um) | RMS / '
             'without | trips | bag complete | client msg/s (channels) | CPU s/s, RSS MB '
             'per process |', '|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        procs = ', '.join('%s %.2f / %.0f' % (k, v.get('cpu_per_s') or 0, v.get('rss_mb', 0))
                          for k, v in sorted(r['processes'].items()))
        c = r.get('client')
        lines.append('| %s | %s %% | %s | %s / %s | %s | %s | %s | %s | %s | %s |' % (
            r['run'], f(r['cycles_kept'], 100, '%.2f'), r['missed_cycles'],
            f(r['latency_p50_s'], 1e3), f(r['latency_p99_s'], 1e3), f(r['rms_m'], 1e6, '%.3f'),
            f(r['rms_m'] / base if r['rms_m'] and base else None, 1, '%.3f'),
            r['watchdog_trips'], r['bag_complete'],
            '%s (%d)' % (f(c['messages_per_s'], 1, '%.0f'), c['channels']) if c else '-',
            procs or r.get('error') or '-'))
    return '\n'.join(lines)


def main(argv=None):
    """Run the benchmark; print the table (and write JSON with ``--json``)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--seconds', type=float, default=10.0)
    ap.add_argument('--pairs', type=int, default=1, help='runs without and with the view')
    ap.add_argument('--hogs', type=int, default=0, help='busy loops beside the graph')
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
            for _ in range(a.hogs)]
    note = ', %d hog(s)' % a.hogs if a.hogs else ''
    rows = []
    try:
        with tempfile.TemporaryDirectory(prefix='bench_live_') as tmp:
            for i in range(a.pairs):
                for live in (False, True):
                    rows.append(run_once(tmp, '%d_%s' % (i, 'live' if live else 'plain'),
                                         a.seconds, live, note))
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    print('load average %s' % (os.getloadavg(),))
    print(table(rows))
    if a.json:
        with open(a.json, 'w', encoding='utf-8') as f:
            json.dump({'rows': rows, 'seconds': a.seconds, 'pairs': a.pairs, 'hogs': a.hogs,
                       'time': time.time()}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
