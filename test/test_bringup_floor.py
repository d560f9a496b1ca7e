# SPDX-License-Identifier: Apache-2.0
"""The machine-floor probe beside a realtime run: its count, its stop, its summary lines."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from fiber_align.analysis import run_summary as sm
from fiber_align.control.cycle import cycle_warning
from fiber_align.control.deadline import DeadlineGrid
from fiber_align.bringup.floor import Floor
from procs import alive

GOAL = 0.001


def test_a_wake_up_on_time_loses_nothing_and_a_late_one_the_deadlines_it_passed():
    g = DeadlineGrid(0.001, 10.0)
    assert g.wake(10.0012) == pytest.approx(10.002)     # the first deadline, 0.2 ms late
    assert g.wake(10.0020001) == pytest.approx(10.003)
    # woken 27.5 periods after the deadline it slept for: 27 deadlines passed unserved
    assert g.wake(10.0305) == pytest.approx(10.031)
    assert (g.ticks, g.lost) == (3, 27)
    assert g.stalls == [(10.0305, 27)]
    f = g.figures(10.0310)
    assert f['periods'] == 31 and f['lost'] == 27
    assert f['lost_share'] == pytest.approx(27 / 31)
    assert f['stalls'] == 1 and f['worst_stall_s'] == pytest.approx(0.028)


def test_a_run_over_its_cycle_goal_is_a_warning_that_names_both_figures():
    assert cycle_warning({'missed_share': 0.0025, 'periods': 60000}, 0.001) == (
        'missed 0.25 % of the cycles since the run started (goal <= 0.1 %)')
    assert cycle_warning({'missed_share': 0.001, 'periods': 60000}, 0.001) is None
    assert cycle_warning({'missed_share': 0.5, 'periods': 0}, 0.001) is None
    assert cycle_warning({'missed_share': 0.5, 'periods': 100}, 0.0) is None   # off


def test_the_graph_is_held_to_its_goal_beyond_the_machines_floor():
    floor = {'lost_share': 0.0020, 'stalls': 9, 'worst_stall_s': 0.049}
    # all of it the machine's: no goal missed, one MACHINE line that says why
    s = {'realtime': {'missed_share': 0.0025}, 'floor': floor}
    assert sm.beyond_floor(0.0025, floor) == pytest.approx(0.0005)
    assert sm.goals_missed(s, 'realtime', GOAL) == []
    line = sm.machine_limit(s, 'realtime', GOAL)
    assert '0.25 %' in line and '0.2 %' in line and '9 stalls' in line and '49 ms' in line
    text = sm.format_summary(dict(s, machine_limits=[line]))
    assert '| MACHINE |' in text and '| machine floor (bare loop beside the graph) | lost 0.2 %' \
        in text
    # beyond the floor by more than the goal: the graph's own
    s = {'realtime': {'missed_share': 0.0035}, 'floor': floor}
    assert sm.goals_missed(s, 'realtime', GOAL) == [
        "missed 0.35 % of the cycles (goal <= 0.1 %), 0.15 % beyond the machine's floor"]
    assert sm.machine_limit(s, 'realtime', GOAL) is None
    # no floor (or its error): every missed cycle counts
    for fl in (None, {'error': 'no figures'}):
        s = {'realtime': {'missed_share': 0.0025}, 'floor': fl}
        assert sm.goals_missed(s, 'realtime', GOAL) == [
            'missed 0.25 % of the cycles (goal <= 0.1 %)']
        assert sm.machine_limit(s, 'realtime', GOAL) is None
    # no goal (0): nothing missed counts
    assert sm.goals_missed(s, 'realtime', 0.0) == []
    assert sm.machine_limit(s, 'realtime', 0.0) is None
    # within the goal: nothing to say
    s = {'realtime': {'missed_share': 0.0005}, 'floor': floor}
    assert sm.goals_missed(s, 'realtime', GOAL) == []
    assert sm.machine_limit(s, 'realtime', GOAL) is None


@pytest.mark.ros  # starts processes
def test_the_probe_counts_the_periods_of_its_run_and_stops_on_sigint(tmp_path):
    probe = Floor(1000.0, 0, str(tmp_path))
    try:
        time.sleep(1.0)
        t0 = time.monotonic()
        f = probe.stop()
        assert time.monotonic() - t0 < 2.0
    finally:
        if probe.proc.poll() is None:
            probe.proc.kill()
    assert 'error' not in f, f
    assert probe.proc.returncode == 0
    # about a second of 1 kHz periods (start-up of the interpreter not counted)
    assert 500 <= f['periods'] <= 1500 and f['rate_hz'] == 1000.0
    assert f['scheduling'] == 'SCHED_OTHER'
    assert f['lost_share'] == pytest.approx(f['lost'] / f['periods']) and f['lost_share'] < 0.1
    assert f['lost'] >= f['stalls'] == len(f['stall_times_s'])
    # the machine's speed: a fixed piece of work, timed on about every tenth tick
    assert 1e-7 < f['work_median_s'] < 0.05, f
    assert probe.stop() is f


@pytest.mark.ros  # starts processes
def test_the_probe_ends_and_writes_its_figures_when_its_launcher_is_killed(tmp_path):
    code = ('import sys, time\n'
            'from fiber_align.bringup.floor import Floor\n'
            'p = Floor(1000.0, 0, sys.argv[1])\n'
            'print(p.proc.pid, flush=True)\n'
            'time.sleep(60)\n')
    launcher = subprocess.Popen([sys.executable, '-c', code, str(tmp_path)],
                                stdout=subprocess.PIPE, text=True)
    pid = None
    try:
        pid = int(launcher.stdout.readline())
        time.sleep(1.0)
        launcher.kill()
        launcher.wait(5)
        end = time.monotonic() + 2.0
        while alive(pid) and time.monotonic() < end:
            time.sleep(0.02)
        assert not alive(pid), 'the probe outlived its launcher by 2 s'
        f = json.loads((tmp_path / 'floor.json').read_text(encoding='utf-8'))
        assert f['periods'] > 0
    finally:
        if launcher.poll() is None:
            launcher.kill()
        if pid is not None and alive(pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.ros  # starts a process
def test_the_probe_starts_light_no_numpy_no_rclpy_one_thread():
    """
    The probe imports the standard library only: it runs at once on a loaded machine.

    Its import went through ``fiber_align.bringup`` (the whole harness, numpy and its
    BLAS threads) until 2026-12-06: under load it started after SIGINT and counted 0
    periods, and the kernel's thread count (numpy's BLAS thread) did not tell whether it ran.
    """
    # the kernel's count (/proc): numpy's BLAS threads are not Python threads
    code = ('import sys\n'
            'import fiber_align.control.floor_probe\n'
            'heavy = sorted(m for m in ("numpy", "rclpy", "fiber_align.bringup")'
            ' if m in sys.modules)\n'
            'status = open("/proc/self/status").read()\n'
            'print(heavy, status.split("Threads:")[1].split()[0])\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60, check=True).stdout.split()
    assert out == ['[]', '1'], out
