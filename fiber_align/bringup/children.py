# SPDX-License-Identifier: Apache-2.0
"""
Node processes of ``bringup``: started, relayed, stopped, never left behind.

Each child runs in a session of its own (Ctrl-C reaches ``bringup``, which stops them in
order) and watches its parent (:func:`fiber_align.lifeline.watch_parent`): ``bringup``
killed with SIGKILL, every node still stops cleanly, its bag finalised.
"""

import collections
import json
import math
import signal
import subprocess
import sys
import threading
import time

from fiber_align.nodes.ros.runtime import STACKS_SIGNAL
from fiber_align.nodes.ros.teardown import SENT_PREFIX
from fiber_align.procstat import cpu_time_s, rss_bytes

#: lines of a child's output kept for the report of a stop that overran
TAIL_LINES = 60
#: exit codes that say why themselves: a clean stop (0; 130 / 143: a second SIGINT /
#: SIGTERM during it) and bad parameters (2: the node's one-line refusal, relayed)
CLEAN_EXITS = (0, 2, 130, 143)


class Child:
    """One node process; relays its output and collects its exit reports."""

    def __init__(self, name, cmd, env, quiet):
        """Start ``cmd`` (a list) in its own session (it ends with this process)."""
        self.name = name
        self.sent = {}               # node name -> {topic: count} (exit reports)
        self.quiet = quiet
        self.last_error = ''
        self.tail = collections.deque(maxlen=TAIL_LINES)   # its latest output lines
        self.cpu0 = None             # (monotonic s, CPU s) at :meth:`mark`
        self.t_interrupt = None      # monotonic s of the first SIGINT
        self.stop_s = None           # s from the SIGINT to the exit (None: not stopped)
        self.killed = False          # escalated to SIGKILL
        self.reported = False        # an unclean exit's output was printed
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
            self.tail.append(line)
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
            if self.t_interrupt is None:
                self.t_interrupt = time.monotonic()
            self.proc.send_signal(signal.SIGINT)

    def wait(self, timeout):
        """Wait for exit; SIGKILL after ``timeout`` s. Return the exit code."""
        try:
            self.proc.wait(timeout=max(0.0, timeout))
        except subprocess.TimeoutExpired:
            self.killed = True
            self._dump_stacks()
            self.proc.kill()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:   # not even SIGKILL ends it yet (the kernel)
                print('bringup: %s (pid %d) still runs 5 s after SIGKILL' % (
                    self.name, self.proc.pid), flush=True)
        if self.t_interrupt is not None and self.stop_s is None:
            self.stop_s = time.monotonic() - self.t_interrupt
        self.thread.join(timeout=1.0)
        code = self.proc.returncode
        if self.killed:
            print('bringup: %s did not exit %.1f s after SIGINT: killed (SIGKILL); its last'
                  ' output:\n%s' % (self.name, self.stop_s or 0.0,
                                    ''.join('  | ' + ln for ln in self.tail)), flush=True)
        elif code not in CLEAN_EXITS and not self.reported:
            # a quiet run relays nothing: the exit's reason is in these lines
            print('bringup: %s exited %d; its last output:\n%s' % (
                self.name, code, ''.join('  | ' + ln for ln in list(self.tail)[-20:])),
                flush=True)
        self.reported = True
        return code

    def _dump_stacks(self, wait_s=0.3):
        """Ask the overrunning child for its threads' stacks (it prints them)."""
        try:
            self.proc.send_signal(STACKS_SIGNAL)
        except OSError:
            return
        try:
            self.proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            pass

    def mark(self):
        """Start the CPU count of :meth:`usage` (the run's start)."""
        self.cpu0 = (time.monotonic(), cpu_time_s(self.proc.pid))

    def usage(self):
        """Return CPU (s per s since :meth:`mark`) and resident memory (MB)."""
        t_a, c_a = self.cpu0 or (math.inf, 0.0)      # not marked: the start failed
        wall = time.monotonic() - t_a
        return {'cpu_per_s': (cpu_time_s(self.proc.pid) - c_a) / wall if wall > 0 else None,
                'rss_mb': rss_bytes(self.proc.pid) / 1e6}


def wait_all(children, timeout, poll_s=0.01):
    """
    Wait for every child to exit, each timed on its own; SIGKILL those left at ``timeout`` s.

    Each child's ``stop_s`` is its own time from its SIGINT to its exit (a sequential
    wait would time the later ones by the earlier ones).
    """
    end = time.monotonic() + max(0.0, timeout)
    left = list(children)
    while left and time.monotonic() < end:
        for ch in list(left):
            if not ch.alive():
                ch.wait(0.0)
                left.remove(ch)
        if left:
            time.sleep(poll_s)
    for ch in left:
        ch.wait(0.0)
