# SPDX-License-Identifier: Apache-2.0
"""
``ros2 launch fiber_align fiber_align.launch.py rig:=true``: the two-axis rig as a user starts it.

The launch file builds the rig from ``graph/rig.py`` (the same description ``bringup
--rig`` uses); with the colcon-built package and the ``ros2`` command line
(``test_ros2_cli.py``'s environment), ``ros2 service call /<ns>/align`` aligns to
TRACKING (realtime; the two axes' loops, the optics and the sequencer all take part), and
SIGINT stops every process cleanly (exit 0, no FATAL, no traceback). Every wait is
bounded; the launch is stopped by its pid and group.
"""

import json
import re
import signal

import pytest

from procs import wait_log
from test_ros2_cli import ros2, ros2_env, spawn, stop_launch  # noqa: F401

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = 'rigl'


def launch_align_stop(env, log, args, ns, tracking_s=20.0, stop_s=10.0):
    """
    ``ros2 launch`` the graph of ``args``, align it by ``ros2 service call``, SIGINT it.

    Asserts TRACKING within ``tracking_s`` (s) after the call and a clean stop (exit 0 within
    ``stop_s``, no FATAL, no traceback); the launch is stopped by its pid and group.
    """
    proc = spawn(env, ['ros2', 'launch', 'fiber_align', 'fiber_align.launch.py'] + args, log)
    try:
        assert wait_log(log, 'startup done', 60.0, proc), log.read_text()[-4000:]
        assert wait_log(log, 'sample clock started', 30.0, proc), log.read_text()[-4000:]
        # TRACKING needs every node: each axis's loop, the optics, the sequencer
        rc, out = ros2(env, 'service', 'call', '/%s/align' % ns, 'std_srvs/srv/Trigger',
                       timeout=30.0)
        assert rc == 0 and 'success=True' in out, out
        assert wait_log(log, 'state TRACKING', tracking_s, proc), log.read_text()[-4000:]
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=stop_s) == 0
        text = log.read_text(errors='replace')
        assert 'FATAL' not in text and 'Traceback' not in text, text[-4000:]
        # the sequencer logs its core's findings, each peak pattern (a FAULT's log then
        # says how it came): the rig's crosses, the station's joint patterns
        assert re.search(r'(cross|pattern) 1 at \(', text), text[-4000:]
    finally:
        stop_launch(proc)


def test_launch_rig_aligns_and_stops_cleanly(ros2_env, tmp_path):  # noqa: F811
    launch_align_stop(ros2_env, tmp_path / 'launch.log',
                      ['rig:=true', 'seed:=0', 'namespace:=' + NS], NS)


def test_launch_station_records_aligns_and_stops_cleanly(ros2_env, tmp_path):  # noqa: F811
    """``station:=true record:=DIR``: ``/<ns>/align`` to TRACKING, a bag of every axis."""
    bag = tmp_path / 'bag'
    launch_align_stop(ros2_env, tmp_path / 'launch.log',
                      ['station:=true', 'seed:=2', 'namespace:=stl', 'record:=%s' % bag],
                      'stl', tracking_s=30.0, stop_s=20.0)
    counts = json.loads((bag / 'recorder_counts.json').read_text(encoding='utf-8'))
    for axis in ('in/x', 'in/y', 'out/x', 'out/y'):
        for topic in ('displacement', 'reference', 'drive_voltage'):
            assert counts['/stl/%s/%s' % (axis, topic)] > 100, counts
    assert counts['/stl/optical_power'] > 100 and counts['/stl/alignment_state'] >= 4
