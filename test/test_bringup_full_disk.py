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

The periods: the issue asks for the cycles kept as without recording. Measured on the
2-core machine (docs/records.md), recording costs periods itself, full disk or not: 30 s
sine runs missed 0.05-0.18 % unrecorded, 0.23-0.34 % recorded into a 500 MB tmpfs and
0.19-0.60 % into this 5 MB one. That item is not met; the bound here (under 1 %, 300
periods) holds the full disk to costing no more than recording does, not to the goal.
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
#: share of the periods missed beyond the machine's floor (module docstring)
MISSED_MAX = 0.01


def test_a_full_disk_stops_the_recording_and_the_run_goes_on(tmp_path):
    summary = tmp_path / 'summary.json'
    with procs.tmpfs(tmp_path / 'fs', FS_BYTES) as fs:
        bag = fs / 'bag'
        code, out = procs.run_bounded(BRINGUP + [
            '--scenario', 'sine', '--sync', 'realtime', '--duration', str(DURATION_S),
            '--record', str(bag), '--summary', str(summary)], 240)
        s = json.loads(summary.read_text(encoding='utf-8'))
        print(out[-3000:])
        assert code == 0, out[-4000:]
        full = [ln for ln in out.splitlines() if 'the disk is full' in ln]
        assert len(full) == 1 and str(bag) in full[0], out[-4000:]
        assert 'Traceback' not in out and 'FATAL' not in out, out[-4000:]
        assert 'the disk is full' in s['recording_stopped_early'], s
        # the run went its 30 s to the end (the recorder no longer ends it); its periods
        # missed no more than a recorded run's (the module docstring's figures)
        rate = float(s['rate_hz'])
        assert s['sent']['simulated_actuator']['displacement'] >= 0.99 * DURATION_S * rate, s
        rt = s['realtime']
        assert rt['missed_share'] - s['floor']['lost_share'] < MISSED_MAX, s
        print('periods %d, missed %d (%.4f %%); floor lost %.4f %%; %s' % (
            rt['periods'], rt.get('missed_cycles', -1), 100 * rt['missed_share'],
            100 * s['floor']['lost_share'], s['recording_stopped_early']))
        assert (bag / 'metadata.yaml').is_file() and not (bag / '.reserve').exists()
        code, text = procs.run_bounded(ANALYZE + [str(bag)], 120)
        assert code == 0 and 'Traceback' not in text, text[-3000:]
        print(text[-1500:])
