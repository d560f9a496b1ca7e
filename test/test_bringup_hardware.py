# SPDX-License-Identifier: Apache-2.0
"""The sensorless hardware graph (processes of ``build_hardware``) on the emulators."""

import pytest

from bench.bench_hardware import graph_trial


@pytest.mark.ros  # starts a process
def test_sensorless_graph_aligns_on_the_emulators():
    r = graph_trial(seed=5, slot_m=41e-6)
    assert r['aligned'], r['status']
    assert r['align_wall_s'] <= 3.0, r
    assert r['final_loss_db'] < 0.1, r
    lo, hi = r['v_range']
    assert 0.0 <= lo and hi <= 100.0 and r['commands'] > 50
    assert all(code == 0 for code in r['exit_codes'].values()), r['exit_codes']


def test_hardware_graph_description(tmp_path):
    from pathlib import Path

    import pytest
    import yaml

    from fiber_align.graph import description as graph
    from fiber_align.graph.hardware import build_hardware
    g = build_hardware(port='/dev/ttyUSB7', visa_resource='TCPIP::h::1::SOCKET',
                       composed='false', record=str(tmp_path / 'bag'))
    assert [p.name for p in g.processes] == [
        'alignment_sequencer', 'hysteresis_compensator', 'actuator_driver', 'power_meter',
        'lifecycle_manager', 'bag_recorder']
    names = [Path(f).name for f in g.params_files]
    assert names[-3:] == ['fiber_align.yaml', 'hardware.yaml', 'sequencer_hardware.yaml']
    drv = g.node_params('actuator_driver')
    assert (drv['backend'], drv['port'], drv['sensorless'], drv['v_min']) == (
        'mdt693b', '/dev/ttyUSB7', True, 0.0)
    assert g.node_params('power_meter')['resource'] == 'TCPIP::h::1::SOCKET'
    assert g.node_params('alignment_sequencer')['rate_hz'] == 100.0
    assert g.node_params('lifecycle_manager')['node_names'] == ['actuator_driver']
    assert g.controller == 'feedforward' and g.managed_nodes == ('actuator_driver',)
    assert 'simulated_actuator' not in g.nodes and 'fuzzy_pid_controller' not in g.nodes
    # the simulated graph is untouched: no hardware file, the topic backend
    sim = graph.build()
    assert sim.node_params('actuator_driver')['backend'] == 'topic'
    assert not sim.node_params('actuator_driver')['sensorless']
    # a params file that turns the backend back to topic is refused, in one line
    user = tmp_path / 'u.yaml'
    user.write_text(yaml.safe_dump({'actuator_driver': {'ros__parameters': {
        'backend': 'topic'}}}))
    with pytest.raises(graph.GraphError, match='backend mdt693b'):
        build_hardware(params_file=str(user))


@pytest.mark.ros  # starts a process
def test_unplugged_amplifier_errors_graph_runs_on_and_reconnects(tmp_path):
    import json
    import time

    from std_srvs.srv import Trigger

    from fiber_align.hardware.bench import emulated
    from fiber_align.bringup.hardware import HardwareRun
    from fiber_align.graph.hardware import build_hardware
    bag = tmp_path / 'bag'
    with emulated(seed=2, slot_position_m=20e-6) as (bench, mdt, pm):
        hw = HardwareRun(build_hardware(port=mdt.port, visa_resource=pm.resource,
                                        record=str(bag)))
        try:
            hw.start()
            assert hw.align()[0], hw.status
            t_unplug = time.monotonic()
            mdt.unplug()
            hw.wait(lambda: hw.obs.watch.level('actuator_driver') == 2, 1.0, 'driver ERROR in 1 s')
            assert time.monotonic() - t_unplug < 1.0
            msg = hw.diag['actuator_driver'][1]
            assert msg.startswith('device lost: MDT693B: ') and '\n' not in msg
            # the driver holds its output: the sequencer holds its setpoint and waits
            hw.wait(lambda: hw.status.get('state') == 'HELD', 1.0, 'sequencer HELD')
            assert 'driver down during TRACKING' in hw.status['hold_reason'], hw.status
            n = len(hw.power)
            time.sleep(0.3)
            hw.alive()                              # every process runs on
            assert len(hw.power) > n + 10           # and the meter still reads
            mdt.plug()
            startup = hw.obs.node.create_client(Trigger, 'lifecycle_manager/startup')
            assert hw.call(startup, Trigger.Request(), 10.0).success
            # OK once the loss's latched ERROR (Health.hold_s, 2 s) has run out
            hw.wait(lambda: hw.obs.watch.level('actuator_driver') == 0, 4.0, 'driver OK again')
            # the re-armed driver: the sequencer re-peaks from the held point by itself
            hw.wait(lambda: hw.status.get('state') == 'TRACKING', 5.0, 'TRACKING again')
            assert hw.align()[0], hw.status        # the reconnected bench aligns again
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes
    counts = json.loads((bag / 'recorder_counts.json').read_text())
    assert counts['/optical_power'] > 100 and counts['/drive_voltage_readback'] > 5, counts


@pytest.mark.ros  # starts a process
def test_bringup_hardware_emulate_end_to_end(tmp_path):
    import json
    import os
    import sys

    from procs import run_bounded
    summary = tmp_path / 's.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', '--hardware',
                             '--emulate', '--slot', '25e-6', '--cycles', '1', '--hold',
                             '0.3', '--quiet', '--summary', str(summary)], timeout=60)
    assert code == 0, out[-2000:]
    s = json.loads(summary.read_text())
    assert s['aligned'] and s['final_state'] == 'TRACKING' and s['align_wall_s'] <= 3.0, s
    assert [[a[0], b[0]] for a, b in s['switch_cycles']] == [[True, True]]
    assert all(c == 0 for c in s['exit_codes'].values()), s['exit_codes']
    # the emulator child is gone with bringup, and so is its serial link
    assert not os.path.exists('/proc/%d' % s['emulator']['pid']) or open(
        '/proc/%d/stat' % s['emulator']['pid']).read().split()[2] == 'Z'
    assert not os.path.exists(s['emulator']['serial_link'])


@pytest.mark.ros  # starts a process
def test_the_emulator_runs_at_the_graph_priority():
    """``bringup --hardware --emulate`` starts the emulator under SCHED_FIFO, as its nodes."""
    import os
    import subprocess

    from fiber_align.graph.hardware import emulator_priority
    from fiber_align.hardware.process import start_emulator, stop_process
    prio = emulator_priority()
    assert prio == 50                       # config/fiber_align.yaml realtime_priority
    probe = subprocess.Popen(['sleep', '10'])
    try:                                    # may this user set SCHED_FIFO at all?
        os.sched_setscheduler(probe.pid, os.SCHED_FIFO, os.sched_param(1))
        allowed = True
    except PermissionError:
        allowed = False
    finally:
        probe.kill()
        probe.wait()
    proc, info = start_emulator(['--seed', '0'], priority=prio)
    try:
        assert info['serial_link'] and info['visa_resource']
        if allowed:
            assert os.sched_getscheduler(proc.pid) == os.SCHED_FIFO
            assert os.sched_getparam(proc.pid).sched_priority == prio
        else:                               # refused: it still runs, at the normal policy
            assert os.sched_getscheduler(proc.pid) == os.SCHED_OTHER
    finally:
        stop_process(proc)
