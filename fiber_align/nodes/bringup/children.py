# SPDX-License-Identifier: Apache-2.0
"""
Node processes of ``bringup``: started, relayed, stopped, never left behind.

Each child runs in a session of its own (a terminal's Ctrl-C reaches ``bringup`` only,
which then stops the children in order) and watches its parent itself, as every
executable of the package does (:func:`fiber_align.lifeline.watch_parent`): if
``bringup`` is killed with SIGKILL, every node still gets a clean stop (the recorder
finalises its bag) instead of running on as an orphan that keeps publishing on the
domain.
"""

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

from fiber_align.nodes.ros.runtime import SENT_PREFIX


class Child:
    """One node process; relays its output and collects its exit reports."""

    def __init__(self, name, cmd, env, quiet):
        """Start ``cmd`` (a list) in its own session (it ends with this process)."""
        self.name = name
        self.sent = {}               # node name -> {topic: count} (exit reports)
        self.quiet = quiet
        self.last_error = ''
        self.cpu0 = None             # (monotonic s, CPU s) at :meth:`mark`
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, bufsize=1,
                                     start_new_session=True)
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

    def mark(self):
        """Start the CPU count of :meth:`usage` (the run's start)."""
        self.cpu0 = (time.monotonic(), cpu_time_s(self.proc.pid))

    def usage(self):
        """Return CPU (s per s since :meth:`mark`) and resident memory (MB)."""
        t_a, c_a = self.cpu0 or (math.inf, 0.0)      # not marked: the start failed
        wall = time.monotonic() - t_a
        return {'cpu_per_s': (cpu_time_s(self.proc.pid) - c_a) / wall if wall > 0 else None,
                'rss_mb': rss_bytes(self.proc.pid) / 1e6}


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
