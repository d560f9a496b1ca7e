# SPDX-License-Identifier: Apache-2.0
"""
``bringup`` stops the ROS way however it is started and stopped, and refuses bad input.

Each case was a defect: started with ``&`` from a script it ignored SIGINT; killed with
SIGKILL it left every node running; a second SIGINT or a SIGTERM during start-up left
a bag no reader could open; bad options and params gave tracebacks or were ignored.
"""

import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

import pytest

import procs
from procs import alive

pytestmark = [pytest.mark.ros, pytest.mark.slow]
BRINGUP = [sys.executable, '-m', 'fiber_align.bringup']


def _pids(text):
    return [int(p) for p in re.findall(r'started \w+ \(pid (\d+)\)', text)]


def _wait_for(path, text, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and text in path.read_text(errors='replace'):
            return path.read_text(errors='replace')
        time.sleep(0.05)
    raise AssertionError('no %r in %s within %g s:\n%s' % (
        text, path, timeout, path.read_text(errors='replace') if path.exists() else ''))


def _gone(pids, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if not any(alive(p) for p in pids):
            return True
        time.sleep(0.05)
    return False


def _kill_all(pids):
    for p in pids:
        if alive(p):
            os.kill(p, signal.SIGKILL)


def _readable(bag):
    from fiber_align.analysis import bag as bagio
    streams, _, topics = bagio.read_streams(str(bag))
    return topics


def test_background_job_of_a_script_stops_on_sigint(tmp_path):
    """`bringup ... &` in a non-interactive sh (SIGINT inherited ignored): kill -INT works."""
    log, pidf = tmp_path / 'log', tmp_path / 'pid'
    script = '%s --scenario none --quiet > %s 2>&1 &\necho $! > %s\nwait\n' % (
        ' '.join(BRINGUP), log, pidf)
    sh = subprocess.Popen(['sh', '-c', script], env=dict(os.environ))
    pids = []
    try:
        text = _wait_for(log, 'graph up', 60)
        pid = int(pidf.read_text())
        pids = [pid] + _pids(text)
        t0 = time.monotonic()
        os.kill(pid, signal.SIGINT)
        sh.wait(timeout=10)
        stop_s = time.monotonic() - t0
        print('stopped %.2f s after kill -INT' % stop_s)
        assert stop_s <= 5.0
        # the whole graph within the same 5 s
        assert _gone(pids, max(0.1, 5.0 - (time.monotonic() - t0))), \
            [p for p in pids if alive(p)]
    finally:
        _kill_all(pids)
        procs.stop(sh, 2.0)


def test_sigkill_leaves_no_node_and_a_finalised_bag(tmp_path):
    """SIGKILL of bringup: every node process ends within 2 s, the recorder closes its bag."""
    bag, log = tmp_path / 'bag', tmp_path / 'log'
    with open(log, 'w') as out:
        proc = subprocess.Popen(BRINGUP + ['--scenario', 'none', '--quiet', '--record',
                                           str(bag)], stdout=out, stderr=subprocess.STDOUT)
    pids = []
    try:
        pids = _pids(_wait_for(log, 'graph up', 60))
        time.sleep(1.0)
        t0 = time.monotonic()
        proc.kill()
        proc.wait(timeout=5)
        assert _gone(pids, 2.0), [p for p in pids if alive(p)]
        print('no graph process left %.2f s after SIGKILL' % (time.monotonic() - t0))
        assert (bag / 'metadata.yaml').is_file()
        assert _readable(bag)['/displacement'][1] > 500
    finally:
        _kill_all(pids)
        procs.stop(proc, 2.0)


def test_second_sigint_still_finalises_the_bag(tmp_path):
    """Two SIGINTs 0.5 s apart: a clean stop, every sent message in a readable bag."""
    import json
    bag, log, summary = tmp_path / 'bag', tmp_path / 'log', tmp_path / 's.json'
    with open(log, 'w') as out:
        proc = subprocess.Popen(BRINGUP + ['--scenario', 'sine', '--sync', 'realtime',
                                           '--quiet', '--record', str(bag), '--summary',
                                           str(summary)],
                                stdout=out, stderr=subprocess.STDOUT)
    pids = []
    try:
        pids = _pids(_wait_for(log, 'graph up', 60))
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 130, log.read_text()
        assert _gone(pids, 2.0)
    finally:
        _kill_all(pids)
        procs.stop(proc, 2.0)
    topics = _readable(bag)
    s = json.loads(summary.read_text())
    for node, counts in s['sent'].items():
        for topic, n in counts.items():
            key = '/' + topic.lstrip('/')
            if n and key in topics:
                assert topics[key][1] == n, (key, topics[key], n)


def test_sigterm_during_start_up_leaves_no_broken_bag(tmp_path):
    """SIGTERM while the graph comes up: it stops, and a bag it began is readable."""
    bag, log = tmp_path / 'bag', tmp_path / 'log'
    with open(log, 'w') as out:
        proc = subprocess.Popen(BRINGUP + ['--scenario', 'sine', '--quiet', '--record',
                                           str(bag)], stdout=out, stderr=subprocess.STDOUT)
    pids = []
    try:
        pids = _pids(_wait_for(log, 'started control_graph', 60))
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) in (130, 1), log.read_text()
        assert _gone(pids, 2.0)
    finally:
        _kill_all(pids)
        procs.stop(proc, 2.0)
    if bag.exists():
        assert (bag / 'metadata.yaml').is_file(), list(bag.iterdir())
        _readable(bag)


@pytest.mark.parametrize('args, words', [
    (['--rate', '0'], '--rate must be > 0'),
    (['--duration', '-1'], '--duration must be > 0'),
    (['--namespace', 'bad name!'], 'namespace'),
    (['-p', 'simulated_actuator:rate_hz:=fast'], 'rate_hz'),
    (['-p', 'simulated_actuator:damping_ration:=0.1'], "did you mean 'damping_ratio'"),
    (['-p', 'no_such_node:x:=1'], 'unknown node'),
    (['--params-file', '{tmp}/typo.yaml'], "unknown parameter 'v_maks'"),
    (['-p', 'simulated_actuator:damping_ratio:=-1.0'], 'damping_ratio'),
    (['-p', 'actuator_driver:v_max:=1000.0'], 'v_max'),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, words):
    """Each bad option or value: exit 2, one `bringup: error:` line naming it."""
    (tmp_path / 'typo.yaml').write_text(
        'actuator_driver:\n  ros__parameters:\n    v_maks: 80.0\n')
    args = [a.replace('{tmp}', str(tmp_path)) for a in args]
    code, out = procs.run_bounded(BRINGUP + ['--scenario', 'none', '--quiet',
                                             '--summary', str(tmp_path / 's.json')] + args,
                                  90)
    errors = [ln for ln in out.splitlines() if 'error' in ln.lower()]
    assert code == 2, out
    assert any(ln.startswith('bringup: error:') and words in ln for ln in errors), out
    assert 'Traceback' not in out, out
    assert len([ln for ln in out.splitlines() if ln.startswith('bringup: error:')]) == 1
    assert not Path(tmp_path / 'typo.yaml_repaired').exists()
