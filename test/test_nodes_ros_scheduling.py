# SPDX-License-Identifier: Apache-2.0
"""The realtime processes' PM QoS request (``nodes.ros.scheduling.CpuLatencyRequest``)."""

import os
import struct
import subprocess
import sys
import time

import pytest

from fiber_align.nodes.ros.scheduling import CpuLatencyRequest

PATH = CpuLatencyRequest.PATH


def _target_us():
    """Return the kernel's CPU latency target now (us): the smallest request in force."""
    fd = os.open(PATH, os.O_RDONLY)
    try:
        return struct.unpack('i', os.read(fd, 4))[0]
    finally:
        os.close(fd)


def _writable():
    return os.path.exists(PATH) and os.access(PATH, os.W_OK)


def test_the_request_holds_zero_while_held_and_ends_at_release():
    req = CpuLatencyRequest()
    if not _writable():
        # not root: the request is refused with the reason, and nothing is held
        text = req.hold()
        assert 'refused' in text and not req.held
        return
    before = _target_us()
    text = req.hold()
    try:
        assert text == 'CPUs held awake' and req.held
        assert _target_us() == 0
        assert req.hold() == 'CPUs held awake'        # a second hold is the same request
    finally:
        req.release()
    assert not req.held and _target_us() == before
    req.release()                                     # idempotent


def test_a_refused_request_says_why_and_holds_nothing(tmp_path):
    req = CpuLatencyRequest()
    req.PATH = str(tmp_path / 'no_such_device')
    text = req.hold()
    assert text.startswith('CPUs not held awake (cpu_dma_latency refused: ') and not req.held
    req.release()


@pytest.mark.ros
def test_the_request_ends_with_a_killed_process():
    writable = _writable()
    before = _target_us() if writable else None
    child = subprocess.Popen(
        [sys.executable, '-c', 'import sys, time\n'
         'from fiber_align.nodes.ros.scheduling import CpuLatencyRequest\n'
         'print(CpuLatencyRequest().hold(), flush=True)\ntime.sleep(60)'],
        stdout=subprocess.PIPE, text=True)
    try:
        text = child.stdout.readline().strip()
        if not writable:
            assert 'refused' in text
            return
        assert text == 'CPUs held awake' and _target_us() == 0
    finally:
        child.kill()
        child.wait(timeout=10)
        child.stdout.close()
    deadline = time.monotonic() + 5.0
    while _target_us() != before and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _target_us() == before
