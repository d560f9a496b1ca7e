# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.bringup.interrupt`: an interrupt cannot be lost."""

import gc
import signal

import pytest

from fiber_align.bringup import interrupt


@pytest.fixture(autouse=True)
def no_pending_interrupt():
    """Each test starts and ends with no interrupt pending (process-wide state)."""
    assert not interrupt.PENDING.is_set()
    yield
    interrupt.handled()


class _Finalized:
    """An object whose finalizer is where the signal lands (an rclpy Future.__del__)."""

    def __del__(self):
        interrupt.handler(signal.SIGINT, None)


@pytest.mark.filterwarnings('ignore::pytest.PytestUnraisableExceptionWarning')
def test_an_interrupt_raised_in_a_finalizer_is_raised_again_at_the_next_check():
    """Python drops the raise inside ``__del__``; the pending mark makes check() raise it."""
    _Finalized()            # collected at once: "Exception ignored in ... __del__"
    gc.collect()
    with pytest.raises(KeyboardInterrupt):
        interrupt.check()
    with pytest.raises(KeyboardInterrupt):
        interrupt.check()   # pending until taken


def test_a_taken_interrupt_is_not_raised_again():
    """After handled() (the run's except clause) the stop's own waits are not interrupted."""
    with pytest.raises(KeyboardInterrupt):
        interrupt.handler(signal.SIGTERM, None)
    interrupt.handled()
    interrupt.check()
