# SPDX-License-Identifier: Apache-2.0
"""Sensorless alignment on the emulated bench, and the ``fiber-align emulate`` process."""

import json
import os
import select
import signal
import subprocess
import sys
import time

import pytest

from fiber_align.alignment import sequencer as sq
from fiber_align.hardware.bench import align_trial, emulated, SensorlessBench

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_sensorless_align_within_0p1_db_in_3_s():
    for seed, slot in ((0, 12e-6), (1, 55e-6)):
        r = align_trial(seed, slot, timeout_s=3.0)
        assert r['aligned'], r['fault_reason']
        assert r['align_wall_s'] <= 3.0
        assert r['final_loss_db'] < 0.1
        # every period wrote one command: the loop ran on the devices
        assert r['commands'] == r['steps']


def test_switch_off_and_on_without_fault():
    with emulated(seed=4, slot_position_m=35e-6) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource, truth=bench.true_loss_db)
        try:
            sb.connect()
            sb.run(lambda b: False, 0.15)
            ok, _ = sb.align()
            assert ok, sb.seq.fault_reason
            for _ in range(3):
                ok, _ = sb.switch(False)
                assert ok and sb.seq.state == sq.IDLE
                # off means dark: the tip parked far from the slot
                assert bench.true_loss_db() > 20.0
                ok, wall = sb.switch(True)
                assert ok, sb.seq.fault_reason
                assert wall <= 3.0            # the align budget; typically 0.3-0.5 s
                losses = sb.hold(0.1)
                assert max(losses) < 0.1
        finally:
            sb.close()


def _run_cli(*args):
    env = dict(os.environ, PYTHONPATH=ROOT)
    return subprocess.Popen([sys.executable, '-m', 'fiber_align.cli', 'emulate', *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, cwd=ROOT)


@pytest.mark.ros  # starts a process
def test_emulate_cli_serves_until_sigterm():
    proc = _run_cli('--slot', '25e-6', '--seed', '3')
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, 'fiber-align emulate printed nothing within 30 s'
        info = json.loads(proc.stdout.readline())
        assert info['serial_port'].startswith('/dev/pts/')
        assert info['visa_resource'].startswith('TCPIP::127.0.0.1::')
        sb = SensorlessBench(info['serial_link'], info['visa_resource'])
        sb.connect()
        sb.step()
        sb.close()
        time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0
        assert json.loads(err.strip().splitlines()[-1])['stopped'] is True
        assert not os.path.exists(info['serial_link'])
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=5)


@pytest.mark.ros  # starts a process
def test_emulate_cli_bad_option_is_one_line_and_exit_2():
    proc = _run_cli('--v-limit', '120')
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert err.strip().splitlines() == [
        "fiber-align emulate: error: --v-limit must be 75, 100 or 150 (the switch), got '120'"]
