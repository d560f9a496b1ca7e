# SPDX-License-Identifier: Apache-2.0
"""No command beyond v_min..v_max or the device limit ever reaches the amplifier."""

import math

import numpy as np
import pytest

from fiber_align.control.driver import DriverCore
from fiber_align.hardware import errors as er
from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import Bench
from fiber_align.hardware.mdt693b_channels import MDT693BOutput

V_MIN, V_MAX = 0.0, 90.0


@pytest.fixture
def emu():
    """Serve an MDT693B emulator with its limit switch at 100 V."""
    e = MDT693BEmulator(Bench(v_limit=100.0))
    yield e
    e.stop()


def _logged(emu):
    return [row[3] for row in emu.command_log]


def test_every_extreme_is_clamped_or_refused_before_the_device(emu):
    out = MDT693BOutput(emu.port, 'x', v_min=V_MIN, v_max=V_MAX, ramp_step_s=0.001)
    assert out.configure()['device_limit_v'] == 100.0
    drv = DriverCore(V_MIN, V_MAX, slew_rate_v_per_s=5e5)
    extremes = [math.nan, math.inf, -math.inf, 1e300, -1e300, 150.0, 100.0000001,
                90.0000001, -1e-9, -20.0, 1e6, -1e6, 45.0, math.nan]
    rng = np.random.default_rng(7)
    burst = list(rng.uniform(-1e4, 1e4, 500)) + [math.nan, math.inf] * 20
    burst += list(np.repeat([-50.0, 250.0], 100))          # steps far beyond the range
    t = 0.0
    for u in extremes + burst:
        t += 1e-3
        out.write(drv.command(u, 0.0, t))      # clamped by the core, checked again
        out.write(drv.command(0.0, u, t))      # same through the feedback input
    # straight into the backend: refused, nothing sent
    n_before = len(emu.command_log)
    for bad in (math.nan, math.inf, -math.inf, -0.1, 90.1, 100.0, 150.0, 1e9):
        with pytest.raises(er.LimitError):
            out.write(bad)
    with pytest.raises(er.LimitError):
        out.ramp_to(120.0)
    assert len(emu.command_log) == n_before
    assert out.refused == 8
    out.ramp_to()                              # back to the safe voltage
    sent = _logged(emu)
    assert len(sent) == out.writes > 2 * len(extremes)
    assert all(math.isfinite(v) and V_MIN <= v <= V_MAX for v in sent)
    assert sent[-1] == 0.0
    out.close()


def test_configure_refuses_v_max_above_the_limit_switch():
    emu = MDT693BEmulator(Bench(v_limit=75.0))
    try:
        out = MDT693BOutput(emu.port, 'x', v_min=0.0, v_max=100.0)
        with pytest.raises(er.LimitError) as info:
            out.configure()
        assert 'exceeds the device limit switch setting 75 V' in str(info.value)
        assert not out.connected
        with pytest.raises(er.DeviceError):
            out.write(10.0)                   # not configured: nothing may be sent
        # a wiring check: the configured device_limit_v must match the device
        out2 = MDT693BOutput(emu.port, 'x', v_min=0.0, v_max=70.0, device_limit_v=150.0)
        with pytest.raises(er.LimitError) as info:
            out2.configure()
        assert 'limit switch is at 75 V' in str(info.value)
        out3 = MDT693BOutput(emu.port, 'x', v_min=-20.0, v_max=70.0)
        with pytest.raises(er.LimitError) as info:
            out3.configure()
        assert 'below 0 V' in str(info.value)
        assert emu.command_log == []
        ok = MDT693BOutput(emu.port, 'x', v_min=0.0, v_max=75.0)
        assert ok.configure()['device_limit_v'] == 75.0
        with pytest.raises(er.LimitError):
            ok.write(75.5)
        ok.write(75.0)
        assert _logged(emu) == [75.0]
        ok.close()
    finally:
        emu.stop()


def test_device_clamps_what_a_careless_client_sends(emu):
    """The emulator itself clamps like the device, and logs the raw command."""
    from fiber_align.hardware.mdt693b import MDT693B
    with MDT693B(emu.port) as c:
        c.transact('xvoltage=250')
        c.transact('xvoltage=-5')
        c.transact('xvoltage=nan')
    assert _logged(emu)[:2] == [250.0, -5.0]
    assert math.isnan(_logged(emu)[2])
    assert 0.0 <= emu.bench.output_v('x') <= 100.0
