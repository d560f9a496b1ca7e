# SPDX-License-Identifier: Apache-2.0
"""``MDT693BChannels`` (several channels on one link) and the emulator's link timing."""

import time

import pytest

from fiber_align.hardware import errors as er
from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import RigBench
from fiber_align.hardware.mdt693b import MDT693B
from fiber_align.hardware.mdt693b_channels import MDT693BChannels

BAUD, TURN = 115200, 1e-3


def axes(**over):
    a = {k: dict(channel=k, v_min=0.0, v_max=100.0, safe_voltage_v=0.0) for k in 'xy'}
    for key, v in over.items():
        axis, _, name = key.partition('_')
        a[axis][name] = v
    return a


@pytest.fixture
def emu():
    e = MDT693BEmulator(RigBench(v_limit=100.0), baud=BAUD, turnaround_s=TURN)
    yield e
    e.stop()


@pytest.mark.parametrize('combined', [False, True])
def test_each_axis_on_its_channel_in_order(emu, combined):
    dev = MDT693BChannels(emu.port, axes(x_channel='z', y_channel='x'), combined=combined)
    dev.configure()
    n = len(emu.command_log)
    sent = [(10.0 + i, 60.0 - i) for i in range(10)]
    for vx, vy in sent:
        dev.write({'x': vx, 'y': vy})
    log = emu.command_log[n:]
    assert [v for _, ch, _, v in log if ch == 'z'] == [vx for vx, _ in sent]
    assert [v for _, ch, _, v in log if ch == 'x'] == [vy for _, vy in sent]
    # the channel no axis owns (y) is only ever re-sent where it was
    assert all(v == 0.0 for _, ch, _, v in log if ch == 'y')
    times = [t for t, *_ in log]
    assert times == sorted(times)
    assert all(text.startswith('xyzvoltage=') == combined for _, _, text, _ in log)
    assert dev.ramp_to_safe() > 0
    assert emu.bench.output_v('z') == 0.0 and emu.bench.output_v('x') == 0.0
    dev.close()


def test_a_firmware_without_xyzvoltage_falls_back_to_one_command_a_channel(emu):
    real = emu._dispatch
    emu._dispatch = lambda cmd: None if cmd.lower().startswith('xyzvoltage') else real(cmd)
    dev = MDT693BChannels(emu.port, axes(), combined=True)
    dev.configure()
    assert not dev.combined and 'CMD_NOT_DEFINED' in dev.combined_refused
    n = len(emu.command_log)
    dev.write({'x': 5.0, 'y': 7.0})
    assert [(ch, v) for _, ch, _, v in emu.command_log[n:]] == [('x', 5.0), ('y', 7.0)]
    dev.close()


@pytest.mark.parametrize('over, model, why', [
    (dict(y_v_max=120.0), 'MDT693B', 'axis y: v_max 120 V exceeds the device limit switch'),
    (dict(x_v_min=-5.0), 'MDT693B', 'axis x: v_min -5 V is below 0 V'),
    ({}, 'MDT694B', 'axis y: channel y does not exist on Model MDT694B'),
])
def test_configure_refuses_and_sends_nothing(over, model, why):
    e = MDT693BEmulator(RigBench(v_limit=100.0), model=model)
    try:
        dev = MDT693BChannels(e.port, axes(**over))
        with pytest.raises(er.LimitError) as exc:
            dev.configure()
        assert why in str(exc.value) and '\n' not in str(exc.value)
        assert not e.command_log and not dev.connected
    finally:
        e.stop()


def test_a_channel_named_twice_is_refused():
    with pytest.raises(ValueError) as exc:
        MDT693BChannels('/dev/null', axes(y_channel='x'))
    assert str(exc.value) == 'channel x is named twice (axes x and y)'


def test_a_refused_value_is_not_sent_the_other_axis_is(emu):
    dev = MDT693BChannels(emu.port, axes(y_v_max=50.0))
    dev.configure()
    n = len(emu.command_log)
    with pytest.raises(er.LimitError):
        dev.write({'x': 20.0, 'y': 80.0})
    assert [(ch, v) for _, ch, _, v in emu.command_log[n:]] == [('x', 20.0)]
    assert dev.outputs['y'].refused == 1
    dev.close()


def test_the_emulated_link_takes_the_byte_times_and_the_turnaround(emu):
    c = MDT693B(emu.port).open()
    try:
        n = 30
        t0 = time.perf_counter()
        for i in range(n):
            c.set_voltage('x', 12.345)
        per = (time.perf_counter() - t0) / n
    finally:
        c.close()
    # 'xvoltage=12.345' + CR in, '>' out: 17 bytes of 10 bits, then the turnaround
    model = 17 * 10.0 / BAUD + TURN
    assert per >= model, (per, model)


@pytest.mark.parametrize('argv, why', [
    (['--target-x', '1e-5'], '--target-x: only with --rig'),
    (['--rig', '--model', 'MDT694B'], '--rig needs two channels; the MDT694B has x only'),
    (['--rig', '--x-channel', 'z', '--y-channel', 'z'],
     "--x-channel and --y-channel name the same channel 'z'"),
    (['--rig', '--x-channel', 'w'], "--x-channel must be x, y or z, got 'w'"),
    (['--rig', '--slot', '1e-5'], '--slot is 1-D; the rig takes --target-x and --target-y'),
    (['--array', '--rig'], '--rig: not available with --array'),
    (['--array', '--x-channel', 'z'], '--x-channel: not available with --array'),
    (['--roll', '1e-3'], '--roll: only with --array'),
    (['--array', '--roll', '0.2'], "--roll must be within -0.1..0.1, got '0.2'"),
    (['--array', '--model', 'MDT694B'], '--array needs three channels; the MDT694B has x only'),
])
def test_emulate_refuses_bad_rig_options_in_one_line(argv, why):
    import argparse

    from fiber_align.hardware import cli
    ap = argparse.ArgumentParser()
    cli.register(ap.add_subparsers())
    with pytest.raises(ValueError) as exc:
        cli.options(ap.parse_args(['emulate'] + argv))
    assert str(exc.value) == why


def test_emulate_rig_options():
    import argparse

    from fiber_align.hardware import cli
    ap = argparse.ArgumentParser()
    cli.register(ap.add_subparsers())
    seed, emu, optics = cli.options(ap.parse_args(
        ['emulate', '--rig', '--seed', '3', '--target-x', '2e-5', '--target-y', '4e-5',
         '--drift', '2e-7', '--drift-y=-2e-7', '--x-channel', 'y', '--y-channel', 'x']))
    assert seed == 3 and emu == {'rig_x_channel': 'y', 'rig_y_channel': 'x'}
    assert optics == {'position_x_m': 2e-5, 'position_y_m': 4e-5, 'drift_x_m_per_s': 2e-7,
                      'drift_y_m_per_s': -2e-7}
