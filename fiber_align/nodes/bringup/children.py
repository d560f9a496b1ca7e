# SPDX-License-Identifier: Apache-2.0
"""
Node processes of ``bringup``: started, relayed, stopped, never left behind.

Each child runs in a session of its own (a terminal's Ctrl-C reaches ``bringup`` only,
which then stops the children in order) and asks the kernel for ``SIGTERM`` when the
thread that started it dies (``prctl(PR_SET_PDEATHSIG)``): if ``bringup`` is killed with
SIGKILL, every node still gets a clean stop (the recorder finalises its bag) instead of
running on as an orphan that keeps publishing on the domain.
"""

import ctypes
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

from fiber_align.nodes._common import SENT_PREFIX

PR_SET_PDEATHSIG = 1
_LIBC = ctypes.CDLL(None, use_errno=True)   # loaded here: the child only calls it


def _die_with_parent(parent_pid):
    """Return a ``preexec_fn``: SIGTERM this child when its parent dies."""
    def set_pdeathsig():
        _LIBC.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != parent_pid:      # the parent died before the prctl
            os.kill(os.getpid(), signal.SIGTERM)
    return set_pdeathsig


class Child:
    """One node process; relays its output and collects its exit reports."""

    def __init__(self, name, cmd, env, quiet):
        """Start ``cmd`` (a list) in its own session, bound to this process's life."""
        self.name = name
        self.sent = {}               # node name -> {topic: count} (exit reports)
        self.quiet = quiet
        self.last_error = ''
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     start_new_session=True,
                                     preexec_fn=_die_with_parent(os.getpid()))
        self.thread = threading.Thread(target=self._relay, daemon=True)
        self.thread.start()

    def _relay(self):
        for line in self.proc.stdout:
            if line.startswith(SENT_PREFIX):
                try:
                    rep = json.loads(line[len(SENT_PREFIX):])
                    self.sent[rep['node'].rsplit('/', 1)[-1]] = rep['sent']
                except (ValueError, KeyError, AttributeError):
                    pass
                continue
            if ': error: ' in line:
                self.last_error = line.strip()
            if not self.quiet:
                sys.stdout.write('[%s] %s' % (self.name, line))
                sys.stdout.flush()

    def alive(self):
        """Return True while the process runs."""
        return self.proc.poll() is None

    def interrupt(self):
        """Send SIGINT (the nodes' clean shutdown)."""
        if self.alive():
            self.proc.send_signal(signal.SIGINT)

    def wait(self, timeout):
        """Wait for exit; SIGKILL after ``timeout`` s. Return the exit code."""
        try:
            self.proc.wait(timeout=max(0.0, timeout))
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(timeout=5)
        self.thread.join(timeout=1.0)
        return self.proc.returncode


def cpu_time_s(pid):
    """Return the user + system CPU time (s) of process ``pid``, or NaN if it is gone."""
    try:
        with open('/proc/%d/stat' % pid, encoding='ascii') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return math.nan


def rss_bytes(pid):
    """Return the resident set size (bytes) of process ``pid``, or NaN if it is gone."""
    try:
        with open('/proc/%d/statm' % pid, encoding='ascii') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')
    except (OSError, IndexError, ValueError):
        return math.nan


def wait_idle(pid, limit_s, window_s=0.1, busy_s=0.011, quiet_windows=2):
    """
    Wait until process ``pid`` is idle; return the wall time waited (s).

    Idle: at most ``busy_s`` CPU seconds in each of ``quiet_windows`` consecutive
    ``window_s`` windows (s); the wait is bounded by ``limit_s`` (s wall).
    """
    t0 = time.monotonic()
    last, quiet = cpu_time_s(pid), 0
    while time.monotonic() - t0 < limit_s:
        time.sleep(window_s)
        now = cpu_time_s(pid)
        if not math.isfinite(now):
            break
        quiet = quiet + 1 if now - last <= busy_s else 0
        last = now
        if quiet >= quiet_windows:
            break
    return time.monotonic() - t0
