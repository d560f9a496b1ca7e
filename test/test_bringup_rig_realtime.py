# SPDX-License-Identifier: Apache-2.0
"""
The two-axis rig in realtime as ``bringup --rig`` runs it: release / align cycles, held.

The composed rig is one process (both axes, the optics, the sequencer) beside the
lifecycle manager; every cycle ends in TRACKING, both axes report their realtime figures
from their own ``/diagnostics`` (the two plants share a base name), with no watchdog trip.
The CPU and cycle goals are the benchmark's (``bench/bench_axis_cpu.py``), not a test's.
"""

import json
import sys

import pytest

from procs import run_bounded

pytestmark = [pytest.mark.ros]


def test_rig_release_align_cycles_in_realtime_end_in_tracking(tmp_path):
    summary = tmp_path / 'rig.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--rig',
                             '--sync', 'realtime', '--cycles', '2', '--duration', '2',
                             '--summary', str(summary), '--quiet'], 120)
    assert code == 0, out
    s = json.loads(summary.read_text(encoding='utf-8'))
    assert s['state'] in ('TRACKING', 'PEAKING') and not s['error'], s
    assert s['cycles_tracking'] == 2 and len(s['cycle_time_to_peak_s']) == 2
    assert all(0.0 < t < 1.0 for t in s['cycle_time_to_peak_s'])
    assert set(s['processes']) == {'rig', 'lifecycle_manager'}
    # CPU counted in clock ticks (10 ms) from the run's start: the rig's two axes at 1 kHz
    # take a good part of a core (0.29-0.39 in docs/realtime.md), the manager is idle
    # after the activation (a diagnostics report every period: far under a tenth of one)
    assert 0.05 < s['processes']['rig']['cpu_per_s'] < 2.0, s['processes']
    assert s['processes']['lifecycle_manager']['cpu_per_s'] < 0.1, s['processes']
    for axis in ('x', 'y'):
        rt = s['axes'][axis]
        # the statistics start after the plant's warm-up (1000 samples)
        # the worst 0.5 s window of the soaks in docs/realtime.md missed 4 %
        assert rt['periods'] > 100 and rt['missed_share'] < 0.1, rt
        assert rt['watchdog_count'] == 0, rt
    assert 'rig CPU:' in out and 'release / align cycles' in out
    # the machine's floor, measured beside the run over its seconds, and printed
    fl = s['floor']
    assert 'error' not in fl and fl['periods'] > 1000, fl
    assert fl['lost_share'] == pytest.approx(fl['lost'] / fl['periods']), fl
    assert fl['lost_share'] < 0.1, fl
    assert 'rig: machine floor (bare loop beside the graph): lost' in out, out
