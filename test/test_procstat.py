# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.procstat`: a process's CPU time and memory from ``/proc``."""

import math
import os
import time

from fiber_align.procstat import cpu_time_s, rss_bytes


def test_this_process_spends_cpu_and_holds_memory_and_a_gone_one_reads_nan():
    c0, end = cpu_time_s(os.getpid()), time.process_time() + 0.05
    while time.process_time() < end:
        pass
    assert cpu_time_s(os.getpid()) - c0 >= 0.03      # clock ticks of 10 ms
    assert rss_bytes(os.getpid()) > 10e6             # Python with pytest loaded
    gone = 2 ** 22 + 1                               # above the kernel's pid_max
    assert math.isnan(cpu_time_s(gone)) and math.isnan(rss_bytes(gone))
