# SPDX-License-Identifier: Apache-2.0
"""
SIGINT and SIGTERM of ``bringup``: a ``KeyboardInterrupt`` that cannot be lost.

The handler raises ``KeyboardInterrupt`` in the main thread wherever it is. Raised while
a finalizer runs (an rclpy ``Future.__del__`` collected in the middle of a wait), Python
prints "Exception ignored in ..." and drops it: a ``kill -INT`` of a ``bringup`` started
as a script's background job was then ignored and the graph ran on
(``test_bringup_signals.py``). The handler therefore also marks the interrupt pending;
every wait loop's liveness check (:func:`check`) raises it again until the run's
``except KeyboardInterrupt`` has taken it (:func:`handled`).
"""

from fiber_align.lifeline import StopFlag

PENDING = StopFlag()


def handler(signum, frame):
    """Mark the interrupt pending and raise ``KeyboardInterrupt`` (the signal handler)."""
    PENDING.set()
    raise KeyboardInterrupt


def check():
    """Raise ``KeyboardInterrupt`` when an interrupt is pending (a lost raise)."""
    if PENDING.is_set():
        raise KeyboardInterrupt


def handled():
    """Note that the interrupt has been taken (the stop runs; no more raises)."""
    PENDING.clear()
