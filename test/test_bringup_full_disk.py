# SPDX-License-Identifier: Apache-2.0
"""
A full disk costs the bag's tail, not the run (issue 39.5).

``bringup --scenario sine --sync realtime --duration 30 --record DIR`` with ``DIR`` on a
real 5 MB tmpfs (mounted here as root with mount(2), unmounted after): the disk fills
after a few seconds. The recorder says so in one line (naming the full disk and the bag),
closes the bag readable and records no more; the graph runs its 30 s to the end, every
sample sent; ``bringup`` exits 0 and its summary says recording stopped early; no
traceback, no FATAL; ``fiber-align analyze`` reads the bag as it is. Before, the recorder
died with FATAL and two tracebacks, ``bringup`` ended the run after 6 s and the bag had
no metadata until ``fiber-align bag-repair``.

The periods: every one run as without recording. The same 30 s run unrecorded comes
first, in the same test; the recorded run may miss at most ``MISSED_TOL`` more of its
periods beyond the machine's floor (the floor probe's own losses). Measured 2026-12-07 on
the 2-core machine, three pairs per tree: unrecorded 0.05-0.12 % beyond the floor, into
this 5 MB tmpfs 0.03-0.11 % (the tree before the gathered chunk writes alike). Earlier
measurements that day gave 0.19-0.60 % into the tmpfs (docs/realtime.md).
"""

import json
import sys

import pytest

import procs

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']
ANALYZE = [sys.executable, '-m', 'fiber_align.cli', 'analyze']
FS_BYTES = 5 * 1024 * 1024
DURATION_S = 30.0
#: more of the periods the recorded run may miss beyond the floor than the unrecorded one:
#: the unrecorded runs' own spread (0.05-0.12 %, module docstring)
MISSED_TOL = 0.001


def _beyond_floor(s):
    """Return the share of the periods a run's summary says it missed beyond the floor."""
    return s['realtime']['missed_share'] - s['floor']['lost_share']


def _run(tmp_path, name, more):
    summary = tmp_path / ('%s.json' % name)
    code, out = procs.run_bounded(BRINGUP + [
        '--scenario', 'sine', '--sync', 'realtime', '--duration', str(DURATION_S),
        '--summary', str(summary)] + more, 240)
    return code, out, json.loads(summary.read_text(encoding='utf-8'))


def test_a_full_disk_stops_the_recording_and_the_run_goes_on(tmp_path):
    code, out, plain = _run(tmp_path, 'unrecorded', [])
    assert code == 0, out[-4000:]
    with procs.tmpfs(tmp_path / 'fs', FS_BYTES) as fs:
        bag = fs / 'bag'
        code, out, s = _run(tmp_path, 'recorded', ['--record', str(bag)])
        print(out[-3000:])
        assert code == 0, out[-4000:]
        full = [ln for ln in out.splitlines() if 'the disk is full' in ln]
        assert len(full) == 1 and str(bag) in full[0], out[-4000:]
        assert 'Traceback' not in out and 'FATAL' not in out, out[-4000:]
        assert 'the disk is full' in s['recording_stopped_early'], s
        # the run went its 30 s to the end (the recorder no longer ends it), its periods
        # kept as the unrecorded run's
        rate = float(s['rate_hz'])
        assert s['sent']['simulated_actuator']['displacement'] >= 0.99 * DURATION_S * rate, s
        print('beyond the floor: recorded %.4f %%, unrecorded %.4f %%; %s' % (
            100 * _beyond_floor(s), 100 * _beyond_floor(plain), s['recording_stopped_early']))
        assert _beyond_floor(s) <= _beyond_floor(plain) + MISSED_TOL, (s, plain)
        assert (bag / 'metadata.yaml').is_file() and not (bag / '.reserve').exists()
        code, text = procs.run_bounded(ANALYZE + [str(bag)], 120)
        assert code == 0 and 'Traceback' not in text, text[-3000:]
        print(text[-1500:])
