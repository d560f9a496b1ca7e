# SPDX-License-Identifier: Apache-2.0
"""
``DriverSession`` on the emulated MDT693B (pure, no ROS): the driver's lifecycle steps.

Configure opens the unit and ramps each axis from where its output is to its safe
voltage; the drives reach the channels through the writer thread; deactivate ramps both
to safe and the writer then sends nothing; a lost unit is reported once, in one line,
and holds the drive; the topic backend (no device) drives the same as DriverAxes alone.
"""

import time

import pytest

from fiber_align.hardware.driver_session import DriverSession, refusal
from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import RigBench
from fiber_align.hardware.mdt693b_channels import MDT693BChannels

PERIOD_S = 0.01
LIMITS = dict(v_min=0.0, v_max=100.0, slew_rate_v_per_s=0.0, watchdog_timeout_s=0.3,
              safe_voltage_v=0.0, latch_trips=3, latch_window_s=10.0,
              safe_ramp_rate_v_per_s=500.0, field_limit_v=150.0, coercive_field_v=120.0,
              depoling_fraction=0.33)
DEVICE = dict(baud=115200, device_limit_v=0.0, device_timeout_s=0.5, ramp_rate_v_per_s=500.0,
              ramp_step_s=0.01, readback_period_s=0.05, combined_write=True)


def axes(**channels):
    return {a: dict(LIMITS, channel=ch) for a, ch in channels.items()}


@pytest.fixture
def emu():
    e = MDT693BEmulator(RigBench(v_limit=100.0), baud=115200, turnaround_s=1e-3)
    yield e
    e.stop()


def feed(s, seconds, values):
    """Feed the feedforwards ``{axis: V}`` and tick every period for ``seconds`` (s)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        now = time.monotonic()
        for a, v in values.items():
            s.input(a, True, v, now)
        s.tick(now)
        time.sleep(PERIOD_S)


def test_open_ramps_from_the_output_drives_then_ramps_to_safe(emu):
    pre = MDT693BChannels(emu.port, {'x': dict(channel='y', v_min=0.0, v_max=100.0,
                                               safe_voltage_v=0.0)})
    pre.configure()
    pre.write({'x': 20.0})                  # a unit left at 20 V
    pre.close()
    s = DriverSession(axes(x='y', y='z'), PERIOD_S, dict(DEVICE, port=emu.port),
                      sensorless=True)
    t0 = time.monotonic()
    s.open()
    ramp = [v for t, ch, _, v in emu.command_log if t >= t0 and ch == 'y']
    # from 20 V (the combined-write probe re-sends it) down in 5 V steps: no jump
    assert ramp[-3:] == [10.0, 5.0, 0.0] and ramp == sorted(ramp, reverse=True)
    assert max(ramp) == 20.0
    assert s.driver.cores['x'].v == 0.0
    kinds = [k for k, _, _ in s.take_reports()]
    assert kinds == ['info', 'ok']
    s.activate()
    feed(s, 0.3, {'x': 30.0, 'y': 40.0})
    assert abs(emu.bench.output_v('y') - 30.0) < 0.2 and abs(emu.bench.output_v('z') - 40.0) < 0.2
    assert s.tick(time.monotonic())[1] or s.dev.readbacks     # read-backs come in
    t1 = time.monotonic()
    drives = s.deactivate(time.monotonic())
    assert sorted(drives) == [('x', 0.0), ('y', 0.0)] and not s.lost
    assert emu.bench.output_v('y') < 0.5 and emu.bench.output_v('z') < 0.5
    n = len(emu.command_log)
    time.sleep(0.2)
    assert len(emu.command_log) == n       # read-back only
    assert [v for t, ch, _, v in emu.command_log if t >= t1 and ch == 'z'][-1] == 0.0
    s.close()


def test_a_lost_unit_is_reported_once_and_holds(emu):
    s = DriverSession(axes(x='x'), PERIOD_S, dict(DEVICE, port=emu.port), sensorless=True)
    s.open()
    s.activate()
    feed(s, 0.1, {'x': 10.0})
    s.take_reports()
    emu.unplug()
    lost = None
    end = time.monotonic() + 2.0
    while lost is None and time.monotonic() < end:
        s.input('x', True, 10.0, time.monotonic())
        lost = s.tick(time.monotonic())[2]
        time.sleep(PERIOD_S)
    assert lost is not None and lost.startswith('MDT693B: ') and '\n' not in lost
    errors = [t for k, _, t in s.take_reports() if k == 'error']
    assert errors == ['device lost: %s' % lost]
    assert s.held and s.tick(time.monotonic())[2] is None    # reported once
    assert s.input('x', True, 12.0, time.monotonic()) == []
    assert s.deactivate(time.monotonic()) == [] and s.lost == lost
    s.close()


def test_topic_backend_drives_as_its_axes_and_refusals_are_one_line():
    s = DriverSession(axes(x='x'), PERIOD_S, lockstep=True)
    s.open()
    assert s.input('x', True, 10.0, 0.0) == [] and s.input('x', False, 1.0, 0.0) == []
    assert s.activate() == [('x', 11.0)]                 # the pair kept while inactive
    assert s.deactivate(0.0) == [('x', 0.0)]
    assert refusal(axes(x='x'), {}, lockstep=True).startswith('backend mdt693b needs')
    assert refusal(axes(x='x', y='x'), {}) == 'channel x is named twice (axes x and y)'
    assert refusal(axes(x='x', y='x'), None) is None     # no device: channels unused
    assert 'field limit' in refusal({'x': dict(LIMITS, channel='x', v_max=160.0)}, None)


def test_topic_backend_realtime_deactivate_ramps_its_drive_to_safe_by_tick():
    """Without a device the ramp is the published drive: deactivate ends at the safe voltage."""
    s = DriverSession(axes(x='x'), PERIOD_S, sensorless=True)
    s.open()
    s.activate()
    assert s.input('x', True, 53.0, 0.0)[-1][1] > 0.0
    assert s.deactivate(0.01) == []
    drives = []
    for k in range(1, 40):                               # 500 V/s: 53 V in about 0.11 s
        drives += s.tick(0.01 + k * PERIOD_S)[0]
    assert drives and drives[-1] == ('x', 0.0), drives
    volts = [v for _, v in drives]
    assert all(b <= a for a, b in zip(volts, volts[1:])), volts        # a ramp down
    assert s.input('x', True, 53.0, 0.5) == [] and s.tick(0.5)[0] == []   # and it stays


def test_a_foreign_publisher_is_an_error_then_a_warn_then_ok_after_the_rearm():
    """Issue 39.1: the steady status every axis shows while held for a foreign publisher."""
    s = DriverSession(axes(x='x', y='y'), PERIOD_S, sensorless=True)
    s.open()
    s.activate()
    s.input('x', True, 40.0, 0.0)
    s.take_reports()
    text = '/x/feedforward_voltage: 2 publishers, 1 expected: foreign /intruder'
    s.intrusion(text)
    reports = s.take_reports()
    assert [k for k, _, _ in reports] == ['error', 'fail'] and reports[1][1] is None
    assert text in reports[1][2] and s.held and s.values()['foreign_publishers'] == text
    assert s.input('x', True, 100.0, 0.1) == [('x', 40.0)]      # held where it is
    s.intrusion(None)
    assert [k for k, _, _ in s.take_reports()] == ['info', 'warn'] and s.held
    s.enable(True, 0.2)
    assert [k for k, _, _ in s.take_reports()] == ['info', 'ok'] and not s.held
    assert s.input('x', True, 50.0, 0.3) == [('x', 50.0)]
