# SPDX-License-Identifier: Apache-2.0
"""
The flight recorder on a realtime 1-D run without full recording (issue 41, item 3).

``bringup --scenario sine --sync realtime --duration 15 --snapshots DIR --catalog DB``
starts the recorder with its bag off and its rings on; 11 s after the graph is up this
test deactivates ``actuator_driver`` through its ``change_state`` service. The driver's
transition event is the trigger: one snapshot bag, which ``fiber-align analyze`` reads
(exit 0), holding at least 9.5 s before and 1.9 s after the trigger (the window's edges
are the messages received inside it), the displacement's stamps without a gap over 1.5
periods but where the plant itself missed a cycle (a late tick publishes no sample: the
run's ``missed_cycles``, on this shared machine a few), and linked from the run's
catalogue row (``snapshot_paths``). No full bag. A missed cycle goal of this shared
machine is a trigger too: its snapshots may come beside.
"""

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pytest

import procs
from test_ros2_cli import spawn

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']
#: s after "graph up" when the driver is deactivated; the run's length (s)
TRIP_S, DURATION_S = 11.0, 15.0
#: lifecycle_msgs Transition id
DEACTIVATE = 4
PERIOD_NS = 1_000_000       # 1 kHz


def test_a_driver_deactivation_writes_one_snapshot_analyze_reads(ctx, tmp_path):
    from lifecycle_msgs.srv import ChangeState
    snaps, db, log = tmp_path / 'snaps', tmp_path / 'catalog.db', tmp_path / 'bringup.log'
    summary = tmp_path / 'summary.json'
    proc = spawn(dict(os.environ), BRINGUP + [
        '--scenario', 'sine', '--sync', 'realtime', '--duration', str(DURATION_S),
        '--snapshots', str(snaps), '--catalog', str(db), '--summary', str(summary)], log)
    try:
        assert procs.wait_log(log, 'bringup: graph up', 60.0, proc), log.read_text()[-3000:]
        node, executor, client = procs.change_state_client(ctx, '/actuator_driver')
        procs.spin_until(executor, lambda: False, TRIP_S)
        req = ChangeState.Request()
        req.transition.id = DEACTIVATE
        fut = client.call_async(req)
        assert procs.spin_until(executor, fut.done, 10.0), 'no answer to change_state'
        assert fut.result().success
        executor.remove_node(node)
        proc.wait(DURATION_S + 30.0)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        procs.stop(proc, 20.0)
    text = log.read_text()
    folders = sorted(p for p in snaps.iterdir() if p.is_dir()) if snaps.exists() else []
    # a shared machine's missed cycle goal is a trigger of its own: more snapshots may be
    ours = [p for p in folders if p.name.endswith('_actuator-driver-inactive')]
    assert len(ours) == 1, (folders, text[-3000:])
    snap = ours[0]
    info = json.loads((snap / 'snapshot.json').read_text())
    assert info['error'] is None, info
    from fiber_align.analysis.bag import read_streams
    streams = read_streams(str(snap))[0]
    d = streams['displacement']
    t_trip = int(round(info['trigger_time_s'] * 1e9))
    before_s, after_s = (t_trip - int(d.t_ns[0])) / 1e9, (int(d.t_ns[-1]) - t_trip) / 1e9
    gaps = np.diff(np.asarray(d.fields['stamp_ns'], np.int64))
    gap = int(gaps.max())
    # a period the plant itself missed (a late tick: no sample) is a gap at the source
    missing = int(np.sum(np.round(gaps[gaps > 1.5 * PERIOD_NS] / PERIOD_NS) - 1))
    missed = int(json.loads(summary.read_text())['realtime']['missed_cycles'])
    run = subprocess.run([sys.executable, '-m', 'fiber_align.cli', 'analyze', str(snap)],
                         capture_output=True, text=True, timeout=120)
    con = sqlite3.connect(str(db))
    paths = [json.loads(r[0] or '[]') for r in con.execute('SELECT snapshot_paths FROM runs')]
    con.close()
    print('snapshot %s: %.3f s before, %.3f s after the trigger, %d displacement samples, '
          'largest stamp gap %.3f ms, %d sample(s) missing, the plant missed %d cycle(s) '
          'in the run; analyze exit %d; runs.snapshot_paths %s' % (
              snap.name, before_s, after_s, len(d.t_ns), gap / 1e6, missing, missed,
              run.returncode, paths))
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert before_s >= 9.5 and after_s >= 1.9, (before_s, after_s)
    assert gap <= 1.5 * PERIOD_NS or missing <= missed, (gap, missing, missed)
    assert len(paths) == 1 and sorted(paths[0]) == [str(p) for p in folders], paths
    assert not list(tmp_path.glob('fiber_align_*')), 'a full bag was written'


#: s: the run of the snapshot-at-the-stop test (the call comes 1 s before its end)
RUN_S = 6.0


def test_a_snapshot_written_at_the_stop_is_linked_in_the_catalogue(ctx, tmp_path):
    """
    A snapshot asked for 1 s before the run ends: written at the recorder's close, linked.

    Its window ends after the run: the recorder writes it when it stops, and announces it
    on ``snapshot_written``; bringup stops the catalogue after the recorder, so the run's
    row has it (with the catalogue stopped beside the recorder, a late snapshot was on
    disk but not in ``snapshot_paths``: a full-suite run, 2026-12-06).
    """
    import rclpy
    from std_srvs.srv import Trigger
    snaps, db, log = tmp_path / 'snaps', tmp_path / 'catalog.db', tmp_path / 'bringup.log'
    proc = spawn(dict(os.environ), BRINGUP + [
        '--scenario', 'sine', '--sync', 'realtime', '--duration', str(RUN_S), '--quiet',
        '--snapshots', str(snaps), '--catalog', str(db)], log)
    try:
        assert procs.wait_log(log, 'bringup: graph up', 60.0, proc), log.read_text()[-3000:]
        t_up = time.monotonic()         # the scenario's RUN_S start about now
        context, nodes = ctx
        node = rclpy.create_node('test_snapshot', context=context)
        nodes.append(node)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        client = node.create_client(Trigger, '/bag_recorder/snapshot')
        assert procs.spin_until(executor, client.service_is_ready, 20.0)
        # 1 s before the run's end, timed from its start: a fixed wait after the service
        # was found (3 s, once) let a slow discovery push the call past the end (no answer:
        # a clean clone's suite, 2026-12-07)
        procs.spin_until(executor, lambda: False, max(0.0, t_up + RUN_S - 1.0 - time.monotonic()))
        # another trigger may have come first (the plant's cycle WARN of a loaded start:
        # a full suite, 2026-12-06): a call inside its window is absorbed, so it is asked
        # again once that window is over (within snapshot_after_s, 2 s)
        t_end = t_up + RUN_S - 0.4
        while True:
            fut = client.call_async(Trigger.Request())
            assert procs.spin_until(executor, fut.done, 10.0), 'no answer to ~/snapshot'
            res = fut.result()
            if res.success or not res.message.startswith('inside the window of') \
                    or time.monotonic() > t_end:
                break
            procs.spin_until(executor, lambda: False, 0.25)
        # refused to the end: another trigger's window covers the stop (a loaded start's
        # cycle WARN 2 s before the end: a full suite, 2026-12-07); that snapshot is then
        # the one written at the stop
        covering = None if res.success else res.message[len('inside the window of '):
                                                        ].rsplit(':', 1)[0]
        assert res.success or res.message.startswith('inside the window of'), res.message
        executor.remove_node(node)
        proc.wait(30.0)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        procs.stop(proc, 20.0)
    folders = sorted(str(p) for p in snaps.iterdir() if p.is_dir())
    assert any(f.endswith('_service') for f in folders) or covering in folders, (
        folders, covering)
    con = sqlite3.connect(str(db))
    paths = [json.loads(r[0] or '[]') for r in con.execute('SELECT snapshot_paths FROM runs')]
    con.close()
    assert len(paths) == 1 and sorted(paths[0]) == folders, (paths, folders)
