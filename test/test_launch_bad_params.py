# SPDX-License-Identifier: Apache-2.0
"""
Bad params files through the real ``ros2 launch`` and ``bringup`` (issue 39.6).

A params file with ``rate_hz: -1000``, a negative ``watchdog_timeout_s`` or a ``v_max``
above the amplifier's limit: ``ros2 launch fiber_align fiber_align.launch.py
params_file:=F`` and ``bringup --params-file F`` refuse it before any process starts
(no "process started" line, no process left in the command's session), exit non-zero,
with one line naming the value. Before, ``control_graph`` exited on the rate while
``ros2 launch`` and ``lifecycle_manager`` waited for the driver until Ctrl-C; the other
two files were accepted until the driver's configure. And a process that exits during
start-up for a reason no range shows (a feedback limit the setpoint range cannot reach)
ends the whole launch with its reason. Every wait is bounded; every process is stopped
by its session.
"""

import os
from pathlib import Path
import signal
import sys
import time

import pytest

from test_ros2_cli import ros2_env, spawn, stop_launch  # noqa: F401

pytestmark = [pytest.mark.ros, pytest.mark.slow]

BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']
#: name -> (params file text, words of the one line)
BAD = {
    'rate': ('/**:\n  ros__parameters:\n    rate_hz: -1000\n', 'rate_hz=-1000'),
    'watchdog': ('actuator_driver:\n  ros__parameters:\n    watchdog_timeout_s: -0.5\n',
                 'watchdog_timeout_s=-0.5'),
    'v_max': ('actuator_driver:\n  ros__parameters:\n    v_max: 120.0\n',
              "outside the amplifier's limits"),
}
#: s: a refusal before any process starts comes within this (the launch's Python start)
REFUSED_WITHIN_S = 30.0


def in_session(sid):
    """Return the pids of the live processes of session ``sid`` (from /proc)."""
    out = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[3]) == sid and fields[0] != 'Z':
            out.append(int(stat.parent.name))
    return out


def _kill_session(sid):
    for pid in in_session(sid):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _run(env, cmd, log, timeout):
    """Run ``cmd`` in a session of its own; return (exit code, output, pids left)."""
    proc = spawn(env, cmd, log)
    try:
        code = proc.wait(timeout=timeout)
        time.sleep(0.5)                 # what it started, if anything, is gone by now
        return code, log.read_text(errors='replace'), in_session(proc.pid)
    finally:
        stop_launch(proc)
        _kill_session(proc.pid)


@pytest.mark.parametrize('name', sorted(BAD))
def test_ros2_launch_refuses_a_bad_params_file_before_any_process(
        ros2_env, tmp_path, name):  # noqa: F811
    text, words = BAD[name]
    f = tmp_path / 'bad.yaml'
    f.write_text(text)
    code, out, left = _run(ros2_env, ['ros2', 'launch', 'fiber_align',
                                      'fiber_align.launch.py', 'params_file:=%s' % f],
                           tmp_path / 'launch.log', REFUSED_WITHIN_S)
    assert code != 0, out
    assert 'process started' not in out, out
    errors = [ln for ln in out.splitlines() if 'ERROR' in ln]
    assert len(errors) == 1 and words in errors[0], out
    assert 'Traceback' not in out and not left, (out, left)


@pytest.mark.parametrize('name', sorted(BAD))
def test_bringup_refuses_a_bad_params_file_before_any_process(tmp_path, name):
    text, words = BAD[name]
    f = tmp_path / 'bad.yaml'
    f.write_text(text)
    code, out, left = _run(dict(os.environ), BRINGUP + [
        '--params-file', str(f), '--scenario', 'sine', '--duration', '5', '--quiet'],
        tmp_path / 'bringup.log', REFUSED_WITHIN_S)
    assert code == 2, out
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith('bringup: error:') and words in lines[0], \
        out
    assert not left, (out, left)


def test_a_process_that_exits_during_start_up_ends_the_launch(
        ros2_env, tmp_path):  # noqa: F811
    """A controller that cannot reach the setpoint range refuses at its start."""
    f = tmp_path / 'limits.yaml'
    f.write_text('/**:\n  ros__parameters:\n    controller: pid\n'
                 'fuzzy_pid_controller:\n  ros__parameters:\n    u_max: 1.0\n')
    t0 = time.monotonic()
    code, out, left = _run(ros2_env, ['ros2', 'launch', 'fiber_align',
                                      'fiber_align.launch.py', 'params_file:=%s' % f],
                           tmp_path / 'launch.log', 60.0)
    took = time.monotonic() - t0
    assert code != 0, out
    last = [ln for ln in out.splitlines() if 'Caught exception in launch' in ln]
    assert len(last) == 1 and 'control_graph exited with code 2 during start-up' in last[0] \
        and 'u_max' in last[0], out
    assert 'waiting for actuator_driver' not in out and not left, (out, left)
    print('the launch ended %.1f s after its start: %s' % (took, last[0]))
