# SPDX-License-Identifier: Apache-2.0
"""Bounded subprocess runs for the integration tests (a hanging test is a failing test)."""

import os
import signal
import subprocess


def run_bounded(cmd, timeout):
    """
    Run ``cmd`` with a timeout (s); return ``(returncode, combined output)``.

    On a timeout the process gets SIGINT first (``bringup`` stops its nodes within 5 s),
    then SIGKILL, so no child outlives the test.
    """
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    out = ''
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
    return proc.returncode, out
