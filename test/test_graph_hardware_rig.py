# SPDX-License-Identifier: Apache-2.0
"""The two-axis rig on hardware (``build_hardware_rig``) through its processes, emulated."""

import time

import pytest

from bench.bench_hardware import graph_trial
from fiber_align.bringup.hardware import HardwareRun
from fiber_align.graph.hardware_rig import build_hardware_rig
from fiber_align.graph.params import GraphError
from fiber_align.hardware.bench import emulated

AMP = 'mdt693b_driver'


def test_hardware_rig_description():
    g = build_hardware_rig(port='/dev/ttyMDT', visa_resource='TCPIP::127.0.0.1::1::SOCKET')
    assert g.namespace == 'rig' and g.managed_nodes == (AMP,)
    assert set(g.nodes) == {'x/hysteresis_compensator', 'y/hysteresis_compensator',
                            'alignment_sequencer_2d', AMP, 'power_meter',
                            'lifecycle_manager'}
    amp = g.node_params(AMP)
    assert amp['port'] == '/dev/ttyMDT' and amp['sensorless'] is True
    assert amp['x']['channel'] == 'x' and amp['y']['channel'] == 'y'
    assert amp['rate_hz'] == 100.0
    assert g.node_params('power_meter')['resource'] == 'TCPIP::127.0.0.1::1::SOCKET'
    seq = g.node_params('alignment_sequencer_2d')
    assert seq['sensorless'] is True and seq['search_speed_m_per_s'] == 200e-6
    for a in 'xy':
        c = g.node_params('%s/hysteresis_compensator' % a)
        assert c['controller'] == 'feedforward' and c['model_file']
    # which channel is which axis is a parameter; a channel twice is refused in one line
    g2 = build_hardware_rig(overrides={AMP: {'x.channel': 'z'}})
    assert g2.node_params(AMP)['x']['channel'] == 'z'
    for over, why in (({'y.channel': 'x'}, 'channel x is named twice'),
                      ({'x.channel': 'w'}, "mdt693b_driver.x.channel 'w' is not one of")):
        with pytest.raises(GraphError) as exc:
            build_hardware_rig(overrides={AMP: over})
        assert str(exc.value).startswith(why) and '\n' not in str(exc.value)


@pytest.mark.ros  # starts processes
def test_the_rig_aligns_through_the_graph_on_one_mdt693b():
    r = graph_trial(seed=3, target_m=(22e-6, 47e-6))
    assert r['aligned'], repr(r)
    assert r['align_wall_s'] < 5.0, r
    assert r['final_loss_db'] < 0.1, r
    lo, hi = r['v_range']
    assert 0.0 <= lo and hi <= 100.0
    # both axes drove their channels; z (no axis) only re-sent its read-back, 0 V
    assert r['commands']['x'] > 50 and r['commands']['y'] > 50
    assert all(code == 0 for code in r['exit_codes'].values()), r['children']


@pytest.mark.ros  # starts processes
def test_unplug_mid_align_error_in_1s_and_recover_on_replug():
    from std_srvs.srv import Trigger
    with emulated(seed=4, rig=True, position_x_m=50e-6, position_y_m=15e-6) as (
            bench, mdt, pm):
        hw = HardwareRun(build_hardware_rig(port=mdt.port, visa_resource=pm.resource))
        try:
            hw.start()
            client = hw.obs.client(Trigger, 'align')
            assert hw.call(client, Trigger.Request()).success
            hw.wait(lambda: hw.status.get('state') == 'SEARCHING', 2.0, 'SEARCHING')
            time.sleep(0.3)
            assert max(bench.output_v('x'), bench.output_v('y')) > 1.0
            # the amplifier unplugged mid-spiral: ERROR within 1 s, one line
            t0 = time.monotonic()
            mdt.unplug()
            hw.wait(lambda: hw.obs.watch.level(AMP) == 2, 1.0, 'amplifier ERROR within 1 s')
            msg = hw.diag[AMP][1]
            assert msg.startswith('device lost: MDT693B: ') and '\n' not in msg, msg
            assert time.monotonic() - t0 < 1.0
            time.sleep(0.3)
            hw.alive()                              # every process runs on
            # re-plugged: the lifecycle reconnects, both axes come back at 0 V first
            mdt.plug()
            n = len(mdt.command_log)
            startup = hw.obs.node.create_client(Trigger, 'lifecycle_manager/startup')
            assert hw.call(startup, Trigger.Request(), 10.0).success
            hw.wait(lambda: hw.obs.watch.level(AMP) == 0, 4.0, 'amplifier OK again')
            after = list(mdt.command_log)[n:]
            for ch in 'xy':
                v = [row[3] for row in after if row[1] == ch]
                assert 0.0 in v, v[:20]
                ramp = v[:v.index(0.0) + 1]         # down to 0 V first, then the align
                assert all(b <= a for a, b in zip(ramp, ramp[1:])), ramp
            # the sequencer goes on with its alignment by itself (or is told again)
            hw.wait(lambda: hw.status.get('state') in ('TRACKING', 'FAULT', 'IDLE'), 10.0,
                    'the alignment resumed')
            if hw.status['state'] != 'TRACKING':
                assert hw.align()[0], hw.status
            assert bench.true_loss_db() < 0.5
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes


@pytest.mark.ros  # starts processes
def test_a_meter_that_stops_answering_mid_spiral():
    from std_srvs.srv import Trigger
    with emulated(seed=6, rig=True, position_x_m=60e-6, position_y_m=5e-6) as (
            bench, mdt, pm):
        hw = HardwareRun(build_hardware_rig(port=mdt.port, visa_resource=pm.resource))
        try:
            hw.start()
            assert hw.call(hw.obs.client(Trigger, 'align'), Trigger.Request()).success
            hw.wait(lambda: hw.status.get('state') == 'SEARCHING', 2.0, 'SEARCHING')
            time.sleep(0.3)
            assert hw.status['state'] == 'SEARCHING'
            assert max(bench.output_v('x'), bench.output_v('y')) > 1.0
            # the meter stops answering: its ERROR (one line) within its 0.5 s timeout
            # and a diagnostics period, and both axes ramp to 0 V (no reading, no step of
            # the sequencer, no feedforward: both watchdogs trip)
            t1 = time.monotonic()
            pm.silent = True
            hw.wait(lambda: hw.obs.watch.level('power_meter') == 2, 1.5, 'meter ERROR')
            assert time.monotonic() - t1 < 1.5
            msg = hw.diag['power_meter'][1]
            assert msg.startswith('PM100: ') and '\n' not in msg, msg
            hw.wait(lambda: max(bench.output_v('x'), bench.output_v('y')) < 0.5, 1.0,
                    'both axes at 0 V')
            hw.alive()                              # every process runs on
            pm.silent = False                       # the meter answers again
            hw.wait(lambda: hw.obs.watch.level('power_meter') == 0, 5.0, 'meter OK again')
        finally:
            codes = hw.stop()
    assert all(c == 0 for c in codes.values()), codes
