# SPDX-License-Identifier: Apache-2.0
"""
CPU of a graph started as ``ros2 launch`` starts it: its processes, nothing watching.

``bench_axis_cpu`` runs each case through ``bringup``, whose observer of the 1-D run
subscribes to ``displacement`` and ``drive_voltage`` over DDS at 1 kHz: the graph then
hands every sample of both to DDS, load a ``ros2 launch`` user does not carry (the rig's
and the station's runs have no such observer). Here the 1-D graph's processes are
started from the one graph description (``graph.description.build`` and each
``Process.command``, as the launch file does), on the sine scenario, with or without
its recorder; after ``--warmup`` s each process's CPU is read from ``/proc`` over
``--seconds``, then every process gets SIGINT. Prints one JSON line: CPU per process
(s/s) and the recorded message counts (the loop ran).

Usage (``PYTHONPATH`` picks the tree measured): ``python bench/graph_cpu.py [--record]
[--seconds 15] [--warmup 8]``.
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time


def _cpu_s(pid):
    """Return the CPU seconds (user + system) of process ``pid`` so far."""
    with open('/proc/%d/stat' % pid) as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def main(argv=None):
    """Start the graph, measure, stop it; print the figures as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    ap.add_argument('--record', action='store_true')
    ap.add_argument('--seconds', type=float, default=15.0)
    ap.add_argument('--warmup', type=float, default=8.0)
    a = ap.parse_args(argv)
    from fiber_align.graph.description import build
    tmp = tempfile.mkdtemp()
    bag = os.path.join(tmp, 'bag')
    g = build(sync_mode='realtime', scenario='sine', record=bag if a.record else '',
              overrides={'scenario_runner': {'duration_s': a.warmup + a.seconds + 30.0}})
    params = g.write_params(os.path.join(tmp, 'params.yaml'))
    procs = []
    try:
        for p in g.processes:
            procs.append((p.name, subprocess.Popen(
                p.command(params, g.namespace, g.remappings, python=sys.executable),
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)))
        time.sleep(a.warmup)
        c0, t0 = {n: _cpu_s(p.pid) for n, p in procs}, time.monotonic()
        time.sleep(a.seconds)
        dt = time.monotonic() - t0
        cpu = {n: (_cpu_s(p.pid) - c0[n]) / dt for n, p in procs}
    finally:
        for _, p in procs:
            p.send_signal(signal.SIGINT)
        for _, p in procs:
            try:
                p.wait(15.0)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    counts = {}
    if a.record and os.path.isfile(os.path.join(bag, 'recorder_counts.json')):
        with open(os.path.join(bag, 'recorder_counts.json'), encoding='utf-8') as f:
            counts = json.load(f)
    shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps({'processes': cpu, 'recorded': counts,
                      'exit_codes': {n: p.returncode for n, p in procs}}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
