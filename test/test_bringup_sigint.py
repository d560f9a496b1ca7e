# SPDX-License-Identifier: Apache-2.0
"""SIGINT to bringup mid-scenario: clean, bounded stop; the bag is complete and readable."""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from procs import alive

pytestmark = [pytest.mark.ros, pytest.mark.slow]

STOP_LIMIT_S = 5.0


def _pids(lines):
    """Return the child pids bringup reported (``bringup: started NAME (pid N)``)."""
    return [int(p) for p in re.findall(r'bringup: started \S+ \(pid (\d+)\)',
                                       ''.join(lines))]


def _threads(pid):
    """Return the number of threads of process ``pid`` (0 if it is gone)."""
    try:
        with open('/proc/%d/status' % pid, encoding='ascii') as f:
            return int(next(ln.split()[1] for ln in f if ln.startswith('Threads:')))
    except (OSError, StopIteration, ValueError):
        return 0


def _bag_counts(bag):
    """Return messages per topic, every message deserialised with rosbags."""
    from rosbags.highlevel import AnyReader
    counts = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


def test_sigint_mid_scenario_stops_cleanly_and_finalises_the_bag(tmp_path):
    """Every process exits within 5 s; bag counts equal what each publisher sent."""
    bag = tmp_path / 'bag'
    summary = tmp_path / 'summary.json'
    # realtime: the 10 s sine is still running when SIGINT comes (lockstep would be
    # done: the composed graph runs 10,000 lockstep samples in about a second)
    cmd = [sys.executable, '-m', 'fiber_align.bringup', '--scenario', 'sine',
           '--sync', 'realtime', '--record', str(bag), '--summary', str(summary), '--quiet']
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines, up, floor = [], threading.Event(), []

    def read():
        for line in proc.stdout:
            lines.append(line)
            if line.startswith('bringup: graph up'):
                up.set()
            floor.extend(int(p) for p in re.findall(r'started machine_floor \(pid (\d+)', line))
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    pids = []
    try:
        assert up.wait(60), ''.join(lines)
        # the floor probe counts once its stdin watcher runs, its one thread beside the main
        # one (it imports the standard library only: test_bringup_floor.py); when it
        # imported the harness, numpy's BLAS thread made two before it ran, and in CI
        # SIGINT came before its first period
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not (floor and _threads(floor[0]) >= 2):
            time.sleep(0.05)
        assert floor and _threads(floor[0]) >= 2, ''.join(lines)
        time.sleep(1.0)                      # ~1,000 of the 10,000 samples
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=STOP_LIMIT_S + 5)
        stop_s = time.monotonic() - t0
        reader.join(timeout=2)
        # the control_graph process (the recorder hosted in it), lifecycle_manager, the
        # catalogue and the machine's floor probe of the realtime run
        pids = _pids(lines)
        assert sorted(re.findall(r'bringup: started (\S+) \(pid', ''.join(lines))) == [
            'control_graph', 'lifecycle_manager', 'machine_floor', 'run_catalog'], \
            ''.join(lines)
        left = [p for p in pids if alive(p)]
        assert stop_s <= STOP_LIMIT_S, 'bringup took %.2f s to exit' % stop_s
        assert code == 130, ''.join(lines)
        assert not left, 'processes left: %s' % left
    finally:
        for p in pids or _pids(lines):
            if alive(p):
                os.kill(p, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=5)
        reader.join(timeout=2)
    s = json.loads(summary.read_text(encoding='utf-8'))
    assert s['interrupted']
    assert 0 < s['samples'] < 10000, 'stopped part-way'
    assert all(ch['exit_code'] == 0 for ch in s['children'].values()), s['children']
    # the machine's floor was measured beside the realtime run, and its probe is gone
    assert 'error' not in s['floor'] and s['floor']['periods'] > 0, s['floor']
    assert not alive(s['floor']['pid'])
    counts = _bag_counts(bag)
    sent = {}
    for node, c in s['sent'].items():
        for topic, n in c.items():
            if n:
                sent['/' + topic.lstrip('/')] = n
    # the recorder records `reference`, the setpoints the loop accepted (all of them)
    assert counts['/reference'] == sent.pop('/setpoint')
    assert set(sent) <= set(counts), (sent, counts)
    assert {k: counts[k] for k in sent} == sent
    assert sent['/displacement'] >= s['samples']
    # a recorded realtime run's figures are its bag's: every sample of it, none read
    # over DDS beside the loop
    assert s['figures_from'] == 'bag' and s['samples'] == counts['/displacement'], \
        (s['samples'], counts)
