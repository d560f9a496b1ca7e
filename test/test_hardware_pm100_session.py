# SPDX-License-Identifier: Apache-2.0
"""The power meter's reading thread without ROS: readings, a lost meter, the recovery."""

import threading
import time

from fiber_align.control.health import ERROR, OK
from fiber_align.hardware import errors as er
from fiber_align.hardware.pm100_session import MeterReader


class FakeMeter:
    """A PM100 that reads 1 mW and fails while ``lost`` is set."""

    resource, ident = 'TCPIP::fake::SOCKET', 'Thorlabs,PM100,fake'

    def __init__(self):
        self.lost = threading.Event()
        self.opened = 0

    def open(self):
        if self.lost.is_set():
            raise er.DeviceError('PM100', er.NO_REPLY, 'fake')
        self.opened += 1

    def configure(self):
        pass

    def read_w(self):
        if self.lost.is_set():
            raise er.DeviceError('PM100', er.NO_REPLY, 'fake')
        return 1e-3

    def errors(self):
        return [(-222, 'Data out of range')]

    def close(self):
        pass


def _wait(cond, bound_s=5.0):
    end = time.monotonic() + bound_s
    while not cond() and time.monotonic() < end:
        time.sleep(0.01)
    return cond()


def test_reader_reads_reports_a_lost_meter_and_reopens_it():
    meter, got, health = FakeMeter(), [], []
    reader = MeterReader(meter, 200.0, 0.05, 0.05, lambda p: got.append(p) or time.time(),
                         lambda level, message: health.append((level, message)))
    reader.start()
    try:
        assert _wait(lambda: len(got) >= 50 and reader.achieved_rate_hz() > 50.0)
        level, message, values = reader.status()
        assert level == OK and message == 'reading %s (%s)' % (meter.resource, meter.ident)
        assert int(values['readings']) >= 50 and values['meter_errors'].startswith('-222 ')
        meter.lost.set()
        assert _wait(lambda: health[-1][0] == ERROR)
        assert health[-1][1].startswith('PM100: ')
        meter.lost.clear()
        assert _wait(lambda: health[-1][0] == OK and meter.opened == 2)
    finally:
        reader.close(1.0)
    assert not reader.thread.is_alive()
