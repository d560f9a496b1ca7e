# SPDX-License-Identifier: Apache-2.0
"""The two-axis rig on hardware as a user starts it: ``bringup --rig --hardware``, launch."""

import json
import os
import subprocess
import sys

import pytest

from procs import run_bounded, run_bringup


def tracked_on_the_emulator(tmp_path, machine, hold_s):
    """Run ``bringup --MACHINE --hardware --emulate --seed 2``; assert TRACKING in 5 s."""
    code, out, s = run_bringup(tmp_path, '--' + machine, '--hardware', '--emulate', '--seed',
                               '2', '--hold', str(hold_s))
    assert code == 0, out[-2000:]
    assert s['aligned'] and s['final_state'] == 'TRACKING' and s['align_wall_s'] < 5.0, s
    assert s['emulator'][machine] is True
    return s


@pytest.mark.ros  # starts processes
def test_bringup_rig_hardware_emulate(tmp_path):
    s = tracked_on_the_emulator(tmp_path, 'rig', 0.3)
    assert all(c == 0 for c in s['exit_codes'].values()), s['exit_codes']
    assert not os.path.exists(s['emulator']['serial_link'])


@pytest.mark.ros  # starts processes
def test_bringup_refuses_v_max_above_the_switch_in_one_line(tmp_path):
    summary = tmp_path / 's.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--rig',
                             '--hardware', '--emulate', '-p', 'mdt693b_driver:y.v_max:=120.0',
                             '--hold', '0.3', '--quiet', '--summary', str(summary)],
                            timeout=60)
    assert code == 1, out[-2000:]
    s = json.loads(summary.read_text())
    assert ('MDT693B: limit: axis y: v_max 120 V exceeds the device limit switch setting '
            '100 V') in s['error'], s
    assert 'Traceback' not in out
    assert all(c == 0 for c in s['exit_codes'].values()), s['exit_codes']


LAUNCH_DESCRIBE = '''
import importlib.util, json, sys
spec = importlib.util.spec_from_file_location('launch_file', sys.argv[1])
m = importlib.util.module_from_spec(spec)
spec.loader.exec_module(m)
args = {n: d for n, d, *_ in m.ARGUMENTS}
args.update(json.loads(sys.argv[2]))
try:
    g = m.describe(args)
    print(json.dumps(dict(kind=type(g).__name__, nodes=list(g.nodes),
                          port=g.node_params('mdt693b_driver')['port'])))
except ValueError as exc:
    print(json.dumps(dict(error=str(exc))))
'''


@pytest.mark.ros  # starts a process (the launch file imports launch_ros)
def test_the_launch_file_reads_the_hardware_rig(tmp_path):
    from pathlib import Path

    from test_ros2_cli import ros2_environment
    env = ros2_environment(Path(sys.prefix)) or dict(os.environ)
    launch = str(Path(__file__).resolve().parents[1] / 'launch' / 'fiber_align.launch.py')
    out = {}
    for name, args in (('rig', dict(rig='true', hardware='true', port='/dev/ttyMDT',
                                    visa_resource='TCPIP::127.0.0.1::1::SOCKET')),
                       ('bad', dict(rig='true', hardware='true', record='b'))):
        # subprocess.run kills the child on its timeout
        proc = subprocess.run([sys.executable, '-c', LAUNCH_DESCRIBE, launch,
                               json.dumps(args)], env=env, capture_output=True, text=True,
                              timeout=60)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        out[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out['rig']['kind'] == 'HardwareRigGraph' and out['rig']['port'] == '/dev/ttyMDT'
    assert 'mdt693b_driver' in out['rig']['nodes']
    assert out['bad'] == {'error': 'record: not available with rig:=true hardware:=true'}
