# SPDX-License-Identifier: Apache-2.0
"""
The fiber array on hardware (``array:=true hardware:=true``): one MDT693B, two PM100s.

The emulator's best is the array optics' best joint pose
(:func:`fiber_align.plant.array_optics.best_pose`: the pose that maximises the worst of
the eight channels' couplings); an outer channel's loss is ``10 log10(c(best) / c(now))``
of its noise-free coupling at the emulated bimorphs' true positions
(:meth:`fiber_align.hardware.emulators.physics.ArrayBench.truth`).
"""

import json
import os
import sys
import time

import pytest

from fiber_align.graph.arguments import describe
from fiber_align.graph.hardware_rig import build_hardware_array
from fiber_align.graph.params import GraphError
from fiber_align.hardware.pm100_session import ReadingSets
from test_bringup_hardware_rig import tracked_on_the_emulator

AMP = 'mdt693b_driver'
TWO = 'TCPIP::127.0.0.1::1::SOCKET,TCPIP::127.0.0.1::2::SOCKET'


def test_hardware_array_description():
    g = describe(dict(array='true', hardware='true', port='/dev/ttyMDT', visa_resource=TWO))
    assert g.namespace == 'array' and g.managed_nodes == (AMP,) and g.scenario == 'array'
    assert {'x/hysteresis_compensator', 'y_left/hysteresis_compensator',
            'y_right/hysteresis_compensator', 'array_sequencer', AMP, 'power_meter',
            'power_meter_n', 'lifecycle_manager'} <= set(g.nodes)
    amp = g.node_params(AMP)
    assert amp['axes'] == ['x', 'y_left', 'y_right'] and amp['port'] == '/dev/ttyMDT'
    assert [amp[a]['channel'] for a in amp['axes']] == ['x', 'y', 'z']
    assert g.node_params('power_meter')['resource'].endswith('1::SOCKET')
    assert g.node_params('power_meter_n')['resource'].endswith('2::SOCKET')
    # the second meter: the one executable, renamed, its power on channel N's topic
    meter_n = [p for p in g.processes if p.name == 'power_meter_n'][0]
    assert meter_n.executable == 'power_meter'
    assert 'optical_power:=optical_power_n' in meter_n.arguments
    seq = g.node_params('array_sequencer')
    assert seq['machine'] == 'array' and seq['sensorless'] is True and seq['rate_hz'] == 100.0
    assert len({seq[k] for k in ('dither_x_frequency_hz', 'dither_left_frequency_hz',
                                 'dither_right_frequency_hz')}) == 3
    refused = ((dict(visa_resource='TCPIP::127.0.0.1::1::SOCKET'), 'visa_resource'),
               (dict(record='b'), 'record: not available with array:=true hardware:=true'),
               (dict(station='true'), 'station:=true'))
    for args, why in refused:
        with pytest.raises(GraphError) as exc:
            describe(dict(array='true', hardware='true', **args))
        assert str(exc.value).startswith(why) and '\n' not in str(exc.value), exc.value
    with pytest.raises(GraphError) as exc:
        build_hardware_array(overrides={AMP: {'axes': ['x', 'y_left']}})
    assert str(exc.value).startswith('mdt693b_driver.axes must be [x, y_left, y_right]')


def test_reading_sets_pair_two_meters_and_let_a_silent_one_show():
    s = ReadingSets(2, 0.01)
    assert s.add(0, 1.0, 0.0) is None
    assert s.add(1, 2.0, 0.004) == (0.0, [1.0, 2.0])
    assert s.add(1, 3.0, 0.011) is None                 # N first this time: waits for 1
    assert s.add(0, 4.0, 0.014) == (0.01, [4.0, 3.0])     # clock: wall gap, at most 1.5 T
    # channel N's meter silent: each reading of channel 1 goes out alone
    assert s.add(0, 5.0, 0.024) is None
    assert s.add(0, 6.0, 0.034) == (0.015 + 0.01, [5.0, None])
    one = ReadingSets(1, 0.01)
    assert one.add(0, 7.0, 0.0) == (0.0, [7.0]) and one.add(0, 8.0, 1.0) == (0.015, [8.0])


@pytest.mark.ros  # starts processes
def test_bringup_array_hardware_emulate_tracks_within_0_1_db(tmp_path):
    s = tracked_on_the_emulator(tmp_path, 'array', 0.5)
    truth = s['truth']                  # the emulator's, at the end of the hold
    assert truth['best_pose'] == pytest.approx(s['emulator']['best_pose'])
    assert len(truth['outer_loss_db']) == 2, truth
    assert all(v <= 0.1 for v in truth['outer_loss_db']), truth
    assert truth['worst_channel_loss_db'] <= 0.2, truth
    assert all(c == 0 for c in s['exit_codes'].values()), s['exit_codes']
    assert not os.path.exists(s['emulator']['serial_link'])


@pytest.mark.ros  # starts processes
@pytest.mark.parametrize('j, name', [(1, "channel N (8)'s power meter"),
                                     (0, "channel 1's power meter")])
def test_a_meter_unplugged_mid_tracking_faults_naming_it_without_drift(j, name):
    from fiber_align.bringup.hardware import HardwareRun
    from fiber_align.hardware.bench import emulated
    from fiber_align.simulation.array_scenarios import random_chip
    c = random_chip(3)
    with emulated(seed=3, array=True, chip_x_m=c[0], chip_y_m=c[1], chip_roll_rad=c[2],
                  layout_seed=3) as (bench, mdt, pm):
        hw = HardwareRun(build_hardware_array(
            port=mdt.port, visa_resource=','.join(m.resource for m in pm)))
        try:
            hw.start()
            ok, _ = hw.align()
            assert ok, hw.status
            time.sleep(0.3)
            assert hw.status['state'] == 'TRACKING'
            assert max(bench.truth()['outer_loss_db']) < 0.3
            # one outer channel's meter unplugged: HELD or FAULT naming it within 1 s
            t0 = time.monotonic()
            pm[j].unplug()
            hw.wait(lambda: hw.status.get('state') in ('HELD', 'FAULT'), 1.0,
                    'HELD or FAULT within 1 s')
            dt = time.monotonic() - t0
            st = hw.status
            why = st['fault_reason'] or st['hold_reason']
            assert name in why and '\n' not in why, st
            assert dt < 1.0
            # never a silent drift: the amplifier's outputs stay where they were
            v0 = [bench.output_v(ch) for ch in 'xyz']
            time.sleep(0.5)
            assert max(abs(bench.output_v(ch) - v) for ch, v in zip('xyz', v0)) < 0.05
            assert hw.status['state'] == st['state']
            meter = ('power_meter', 'power_meter_n')[j]
            hw.wait(lambda: hw.obs.watch.level(meter) == 2, 2.0, 'the meter ERROR')
            assert hw.diag[meter][1].startswith('PM100: ')
            hw.alive()                              # every process runs on
            print('unplug -> %s in %.0f ms: %s' % (st['state'], dt * 1e3, why))
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes


@pytest.mark.ros  # starts a process (the launch file imports launch_ros)
def test_the_launch_file_reads_the_hardware_array():
    import subprocess
    from pathlib import Path

    from test_bringup_hardware_rig import LAUNCH_DESCRIBE
    from test_ros2_cli import ros2_environment
    env = ros2_environment(Path(sys.prefix)) or dict(os.environ)
    launch = str(Path(__file__).resolve().parents[1] / 'launch' / 'fiber_align.launch.py')
    args = dict(array='true', hardware='true', port='/dev/ttyMDT', visa_resource=TWO)
    # subprocess.run kills the child on its timeout
    proc = subprocess.run([sys.executable, '-c', LAUNCH_DESCRIBE, launch, json.dumps(args)],
                          env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out['kind'] == 'HardwareRigGraph' and out['port'] == '/dev/ttyMDT', out
    assert {'mdt693b_driver', 'power_meter', 'power_meter_n', 'array_sequencer'} <= set(
        out['nodes'])
