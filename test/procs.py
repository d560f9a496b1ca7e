# SPDX-License-Identifier: Apache-2.0
"""Bounded subprocess runs for the integration tests (a hanging test is a failing test)."""

import os
import signal
import subprocess
import time


def stop(proc, grace_s=10.0):
    """SIGINT ``proc`` if it still runs, then SIGKILL after ``grace_s`` (s)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def run_bounded(cmd, timeout, grace_s=10.0):
    """
    Run ``cmd`` with a timeout (s); return ``(returncode, combined output)``.

    On a timeout the process gets SIGINT first (``bringup`` and the demo stop their
    nodes cleanly), then SIGKILL after ``grace_s``, so no child outlives the test.
    """
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    out = ''
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        stop(proc, grace_s)
    return proc.returncode, out


def spin_until(executor, cond, bound_s, slice_s=0.01):
    """Spin ``executor`` until ``cond()`` holds or ``bound_s`` (s) pass; return ``cond()``."""
    end = time.monotonic() + bound_s
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=slice_s)
        if cond():
            return True
    return False


def level(status):
    """Return the severity (int) of a diagnostic_msgs/DiagnosticStatus."""
    return status.level[0] if isinstance(status.level, bytes) else int(status.level)
