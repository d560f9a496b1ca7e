# SPDX-License-Identifier: Apache-2.0
"""
The machine's floor beside a realtime graph: a bare loop at the graph's rate and priority.

Not a ROS node: a process of its own that ``bringup`` starts beside every realtime run
(:class:`fiber_align.bringup.floor.Floor`), at the graph's ``SCHED_FIFO`` priority plus
one; it counts the periods it lost by the plant's rule
(:class:`~fiber_align.control.deadline.DeadlineGrid`). Why (a virtual machine stops all
its CPUs at once) and how the summary uses it: docs/realtime.md ("The machine's floor").

Light to start: the standard library only (no numpy, no rclpy, and a package whose
``__init__`` imports nothing), so it runs within tens of milliseconds of its launch even
on a loaded machine, and its only second thread is its standard-input watcher.

Run alone: ``python -m fiber_align.control.floor_probe --rate-hz 1000 --priority 51
--out FILE``; it stops at the end of its standard input (the pipe ``Floor`` holds: closed
by ``Floor.stop``, or by the kernel when the process that started it is gone, however it
ended), on SIGINT or on SIGTERM, and then writes its figures to ``FILE`` (JSON). Nothing
is written while it runs.
"""

import argparse
import json
import os
import signal
import sys
import threading
import time

from fiber_align.control.deadline import DeadlineGrid

#: every this many ticks the probe times a fixed piece of Python work (:func:`work`)
WORK_EVERY = 10
#: the work's size (loop iterations): tens of microseconds, a small part of a period
WORK_N = 500


def work(n=WORK_N):
    """Return the sum of ``range(n)``, added one by one: a fixed piece of Python work."""
    total = 0
    for i in range(n):
        total += i
    return total


def probe(rate_hz, priority, stop):
    """
    Run the bare loop until ``stop()``; return its :meth:`DeadlineGrid.figures`.

    Besides the lost periods: ``work_median_s``, the median time (s) of :func:`work`,
    timed every :data:`WORK_EVERY` ticks: the machine's speed over the run (the same
    graph takes more CPU per period on a slower or busier host, which loses no period
    of a bare loop but more of the graph's).

    :param rate_hz: the loop's rate (Hz). :param priority: ``SCHED_FIFO`` priority
        (0: the normal policy); refused, the loop runs at the normal policy and says so
        in ``scheduling``.
    """
    sched = 'SCHED_OTHER'
    if priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
            sched = 'SCHED_FIFO %d' % priority
        except (AttributeError, OSError) as exc:
            sched = 'SCHED_OTHER (SCHED_FIFO %d refused: %s)' % (priority, exc)
    clock, timer = time.monotonic, time.perf_counter
    grid = DeadlineGrid(1.0 / float(rate_hz), clock())
    deadline = grid.deadline
    work_s = []
    while not stop():
        wait = deadline - clock()
        if wait > 0:
            time.sleep(wait)
        deadline = grid.wake(clock())
        if grid.ticks % WORK_EVERY == 0 and len(work_s) < 1000000:
            t = timer()
            work()
            work_s.append(timer() - t)
    out = grid.figures(clock())
    work_s.sort()
    out.update(scheduling=sched, rate_hz=float(rate_hz), t0_s=grid.t0_s,
               stall_times_s=[round(t, 4) for t, _ in grid.stalls[:1000]],
               work_median_s=work_s[len(work_s) // 2] if work_s else None)
    return out


def main(argv=None):
    """Probe until a stop signal (or the parent is gone); write the figures; return 0."""
    ap = argparse.ArgumentParser(prog='floor', description=__doc__.split('\n\n')[0])
    ap.add_argument('--rate-hz', type=float, required=True, help='loop rate (Hz)')
    ap.add_argument('--priority', type=int, required=True,
                    help='SCHED_FIFO priority (0: normal)')
    ap.add_argument('--out', required=True, help='JSON file the figures go to at the stop')
    a = ap.parse_args(argv)
    flag = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: flag.append(1))

    def until_eof():
        # the launcher's end of the pipe closes at its stop and when it dies, SIGKILL too
        while sys.stdin.buffer.read(4096):
            pass
        flag.append(1)
    threading.Thread(target=until_eof, name='eof', daemon=True).start()
    figures = probe(a.rate_hz, a.priority, lambda: flag)
    tmp = a.out + '.part'
    with open(tmp, 'w', encoding='utf-8') as f:
        json.dump(figures, f)
    os.replace(tmp, a.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
