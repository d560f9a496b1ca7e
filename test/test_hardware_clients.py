# SPDX-License-Identifier: Apache-2.0
"""Outside clients on the emulators: mdt69x on the MDT693B pty, bare pyvisa on the PM100."""

import time

import mdt69x
import pytest
import pyvisa

from fiber_align.hardware import errors as er
from fiber_align.hardware.emulators.mdt693b import MDT693BEmulator
from fiber_align.hardware.emulators.physics import Bench
from fiber_align.hardware.emulators.pm100 import PM100Emulator
from fiber_align.hardware.mdt693b import MDT693B


@pytest.fixture(scope='module')
def bench():
    """One emulated bench for the module (slot at 30 um)."""
    return Bench(slot_position_m=30e-6, seed=1)


def test_mdt69x_sets_and_reads_back_every_channel(bench):
    # mdt69x's port check expects the bare 'CMD_NOT_DEFINED>' of a unit whose echo is off
    emu = MDT693BEmulator(bench, echo=False)
    try:
        c = mdt69x.Controller(emu.port)
        try:
            assert c.get_switch_limit() == 100.0
            for ch, v in (('x', 12.5), ('y', 40.0), ('z', 77.7)):
                assert getattr(c, 'set_%s_voltage' % ch)(v) == mdt69x.Controller.SUCCESS
                time.sleep(0.01)            # the output slews; 0.01 s is plenty
                assert getattr(c, 'get_%s_voltage' % ch)() == pytest.approx(v, abs=0.05)
        finally:
            c.close()
        # mdt69x works in the compatibility set: XV / XR, '*' prompt
        assert emu.compat is True
        assert [row[2] for row in emu.command_log] == ['XV12.5', 'YV40.0', 'ZV77.7']
    finally:
        emu.stop()


def test_own_client_resyncs_from_echo_on_and_compatibility_mode(bench):
    emu = MDT693BEmulator(bench, echo=True, compat=True)
    try:
        with MDT693B(emu.port, timeout_s=0.5) as c:
            assert emu.echo is False and emu.compat is False
            assert 'MDT693B' in c.identify()
            assert c.voltage_limit() == 100.0
            c.set_voltage('y', 33.3)
            time.sleep(0.01)
            assert c.get_voltage('y') == pytest.approx(33.3, abs=0.05)
            with pytest.raises(er.DeviceError) as info:
                c.transact('frobnicate=1')
            assert info.value.reason == er.CMD_NOT_DEFINED
            assert 'frobnicate' in str(info.value)
            # the device still answers after an error
            assert c.voltage_limit() == 100.0
            # with the echo turned back on, replies still parse
            c.transact('echo=1')
            assert c.get_voltage('y') == pytest.approx(33.3, abs=0.05)
    finally:
        emu.stop()


def test_mdt694b_has_only_x(bench):
    emu = MDT693BEmulator(bench, model='MDT694B')
    try:
        with MDT693B(emu.port) as c:
            c.identify()
            assert c.channels == ('x',)
            with pytest.raises(er.DeviceError) as info:
                c.set_voltage('y', 1.0)
            assert info.value.reason == er.CMD_NOT_DEFINED
    finally:
        emu.stop()


def test_bare_pyvisa_reads_idn_and_power(bench):
    emu = PM100Emulator(bench)
    rm = pyvisa.ResourceManager('@py')
    try:
        inst = rm.open_resource(emu.resource, read_termination='\n', write_termination='\n',
                                timeout=1000)
        assert inst.query('*IDN?').startswith('Thorlabs,PM100')
        inst.write('SENS:CORR:WAV 1550')
        inst.write('SENSe:AVERage:COUNt 4')
        assert inst.query('sens:aver:coun?').strip() == '4'
        t0 = time.monotonic()
        p = float(inst.query('MEAS:POW?'))
        # 4 samples of 3 ms each: the reply takes at least 12 ms
        assert time.monotonic() - t0 >= 0.012
        # the tip is at rest at 0 um, 30 um from the slot: only the noise floor
        assert 0.0 <= p < 1e-9
        inst.write('SYST:FOO 1')
        assert inst.query('SYST:ERR?').strip() == '-113,"Undefined header"'
        assert inst.query('SYST:ERR?').strip() == '0,"No error"'
        inst.close()
    finally:
        rm.close()
        emu.stop()


def test_meter_reads_the_optics_at_the_bimorph_position():
    bench = Bench(slot_position_m=20e-6, seed=2, rin_db=0.0, noise_floor_w=0.0)
    mdt = MDT693BEmulator(bench)
    pm = PM100Emulator(bench)
    try:
        from fiber_align.hardware.pm100 import PM100
        meter = PM100(pm.resource).open()
        meter.configure()
        with MDT693B(mdt.port) as c:
            best = (0.0, None)
            for v in range(0, 40, 2):
                c.set_voltage('x', float(v))
                time.sleep(0.02)
                best = max(best, (meter.read_w(), v))
        # the peak is near the voltage whose displacement is 20 um and close to the
        # link's maximum (1 mW, 0.036 dB gap loss)
        assert best[0] > 0.9 * bench.coupling.max_power_w()
        x = bench.advance()
        assert x > 25e-6      # the last command (38 V) pushed the tip past the slot
        meter.close()
    finally:
        pm.stop()
        mdt.stop()
