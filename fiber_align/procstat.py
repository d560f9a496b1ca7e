# SPDX-License-Identifier: Apache-2.0
"""
A process's CPU time and resident memory, read from ``/proc`` (standard library only).

What ``bringup`` reports per process of a graph (CPU s per s, RSS) and what the soak and
flight-recorder benchmarks measure of the processes they start. A process that is gone
reads as NaN.
"""

import math
import os


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
