# SPDX-License-Identifier: Apache-2.0
"""A realtime run ends ``observer_drain_s`` after the runner's done, however far behind."""

import threading
import time
from types import SimpleNamespace

from fiber_align.nodes.bringup.observer import Observer


def state(lockstep=False, done_ago=None, own_done=False):
    done = threading.Event()
    if own_done:
        done.set()
    return SimpleNamespace(lockstep=lockstep, done=done, runner_done_at=None if done_ago is None
                           else time.monotonic() - done_ago)


def test_behind_once_the_runner_is_done_longer_than_the_drain():
    assert Observer.behind(state(done_ago=2.5), 2.0)
    assert not Observer.behind(state(done_ago=1.0), 2.0)


def test_not_behind_before_the_runner_is_done_or_once_the_record_is_complete():
    assert not Observer.behind(state(done_ago=None), 2.0)
    assert not Observer.behind(state(done_ago=5.0, own_done=True), 2.0)


def test_lockstep_always_waits_for_its_own_record():
    # lockstep figures are compared sample for sample: its record must be whole
    assert not Observer.behind(state(lockstep=True, done_ago=60.0), 2.0)
