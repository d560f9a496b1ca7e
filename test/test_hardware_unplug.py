# SPDX-License-Identifier: Apache-2.0
"""Unplugging a device mid-run: a typed error with the reason within 1 s, then reconnect."""

import threading
import time

import pytest

from fiber_align.hardware import errors as er
from fiber_align.hardware.bench import emulated, SensorlessBench


def _until_error(fn, period_s=0.01, bound_s=3.0):
    """Call ``fn`` every period until it raises DeviceError; return (error, time raised)."""
    end = time.monotonic() + bound_s
    while time.monotonic() < end:
        try:
            fn()
        except er.DeviceError as exc:
            return exc, time.monotonic()
        time.sleep(period_s)
    raise AssertionError('no DeviceError within %.1f s' % bound_s)


def _unplug_later(dev, delay_s):
    box = {}

    def go():
        box['t'] = time.monotonic()
        dev.unplug()
    threading.Timer(delay_s, go).start()
    return box


def test_amplifier_unplugged_mid_run_then_reconnected():
    with emulated(seed=0) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource)
        sb.output.configure()
        v = [0.0]

        def write():
            v[0] = (v[0] + 1.0) % 50.0
            sb.output.write(v[0])
        box = _unplug_later(mdt, 0.2)
        exc, t_err = _until_error(write)
        assert t_err - box['t'] < 1.0
        assert exc.reason in (er.PORT_GONE, er.WRITE_ERROR, er.NO_PROMPT)
        assert str(exc).startswith('MDT693B: ') and '\n' not in str(exc)
        assert not sb.output.connected
        with pytest.raises(er.DeviceError):       # still gone: configure says so
            sb.output.configure()
        mdt.plug()                                # re-enumerated: same link, new pty
        assert sb.output.configure()['device_limit_v'] == 100.0
        sb.output.write(12.0)
        time.sleep(0.01)
        assert sb.output.read_back() == pytest.approx(12.0, abs=0.05)
        sb.close()


def test_meter_dropped_mid_run_then_reconnected():
    with emulated(seed=0) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource)
        sb.meter.open()
        sb.meter.configure()
        box = _unplug_later(pm, 0.2)
        exc, t_err = _until_error(sb.meter.read_w)
        assert t_err - box['t'] < 1.0
        assert exc.reason in (er.NO_REPLY, er.PORT_GONE)
        assert str(exc).startswith('PM100: ') and '\n' not in str(exc)
        with pytest.raises(er.DeviceError):
            sb.meter.reconnect()                  # refused while unplugged
        pm.plug()
        assert 'PM100' in sb.meter.reconnect()
        assert sb.meter.read_w() >= 0.0
        sb.close()


def test_unplug_during_alignment_stops_the_loop_with_the_reason():
    with emulated(seed=3, slot_position_m=40e-6) as (bench, mdt, pm):
        sb = SensorlessBench(mdt.port, pm.resource)
        sb.connect()
        sb.seq.align()
        box = _unplug_later(mdt, 0.3)
        with pytest.raises(er.DeviceError) as info:
            sb.run(lambda b: False, 3.0)
        assert time.monotonic() - box['t'] < 1.0
        assert info.value.device == 'MDT693B'
        mdt.plug()
        sb.connect()                              # the whole bench reconnects
        sb.seq.release()
        sb.run(lambda b: False, 0.05)
        sb.close()
