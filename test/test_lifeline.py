# SPDX-License-Identifier: Apache-2.0
"""``lifeline``: the stop flag (a second signal: the exit code); a stuck stop ends later."""

import os
import signal
import subprocess
import sys
import time

import pytest

from fiber_align import lifeline
from fiber_align.lifeline import StopFlag


def test_one_signal_stops_with_the_ordinary_code():
    f = StopFlag()
    assert not f.is_set()
    f.note(signal.SIGINT)
    assert f.is_set() and f.exit_code(0) == 0 and f.exit_code(2) == 2


def test_a_second_signal_during_the_stop_is_reported_the_shell_way():
    f = StopFlag()
    f.note(signal.SIGINT)
    f.note(signal.SIGTERM)
    assert f.exit_code(0) == 128 + signal.SIGTERM


def test_set_and_clear_do_not_count_as_a_signal():
    f = StopFlag()
    f.set()
    f.set()
    assert f.is_set() and f.exit_code(0) == 0
    f.clear()
    assert not f.is_set()


#: the stuck process: its SIGTERM handler runs, but its stop never ends
_STUCK = '''
import signal, sys, time
from fiber_align import lifeline
signal.signal(signal.SIGTERM, lambda *a: None)
lifeline.watch_parent(lifeline.PARENT_PID, signal.SIGTERM, bound_s=%r)
print('ready', flush=True)
while True:
    time.sleep(0.05)
'''
#: the launcher of the stuck process: prints its pid, waits to be killed
_LAUNCHER = '''
import subprocess, sys
p = subprocess.Popen([sys.executable, '-c', sys.argv[1]], stderr=open(sys.argv[2], 'w'))
print(p.pid, flush=True)
p.wait()
'''


def _running(pid):
    """Return True while ``pid`` is a live process (a zombie is not: nobody reaps it)."""
    try:
        with open('/proc/%d/stat' % pid) as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except (OSError, IndexError):
        return False


@pytest.mark.ros
def test_a_process_whose_stop_never_ends_is_ended_after_its_parent(tmp_path):
    """
    The parent killed (SIGKILL), the child's stop hangs: it exits 1 within its bound.

    Node processes whose pytest died of SIGSEGV were found running hours later; the
    bound here is 1 s (the shipped one :data:`lifeline.STOP_BOUND_S`, 30 s).
    """
    err = tmp_path / 'stuck.err'
    launcher = subprocess.Popen([sys.executable, '-c', _LAUNCHER, _STUCK % 1.0, str(err)],
                                stdout=subprocess.PIPE, text=True)
    pid = None
    try:
        pid = int(launcher.stdout.readline())
        assert launcher.stdout.readline().strip() == 'ready'
        launcher.kill()
        launcher.wait(5.0)
        end = time.monotonic() + 1.0 + lifeline.BACKSTOP_S + 3.0
        while _running(pid) and time.monotonic() < end:
            time.sleep(0.05)
        assert not _running(pid), 'the stuck child outlived its parent'
        text = err.read_text()
        assert 'lifeline: the parent process ended 1 s ago' in text, text
        assert 'Current thread' in text or 'Thread 0x' in text, text     # the stacks
    finally:
        launcher.kill()
        if pid is not None and _running(pid):
            os.kill(pid, signal.SIGKILL)
