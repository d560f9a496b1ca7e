# SPDX-License-Identifier: Apache-2.0
"""bringup's child processes: a stop that overruns is killed and says where it hung."""

import contextlib
import os
import sys
import time

import pytest

from fiber_align.bringup.children import Child

pytestmark = pytest.mark.ros

#: A process that takes SIGINT and does not stop, as a node stuck in its teardown would;
#: it registers the stack dump as the node runtime's ``init`` does.
STUCK = """
import faulthandler, signal, sys, time
from fiber_align.nodes.ros.runtime import STACKS_SIGNAL
signal.signal(signal.SIGINT, lambda *a: None)
faulthandler.register(STACKS_SIGNAL, all_threads=True)
def teardown_that_hangs():
    time.sleep(60)
print('ready', flush=True)
teardown_that_hangs()
"""


@contextlib.contextmanager
def started(code):
    """Yield a :class:`Child` running ``code`` once it printed ``ready``; kill it after."""
    child = Child('stuck', [sys.executable, '-c', code], dict(os.environ), quiet=True)
    end = time.monotonic() + 10.0
    while time.monotonic() < end and not any('ready' in ln for ln in list(child.tail)):
        time.sleep(0.01)
    try:
        yield child
    finally:
        if child.alive():
            child.proc.kill()
            child.proc.wait(5)


def test_a_child_that_overruns_its_stop_is_killed_with_its_stacks_reported(capsys):
    with started(STUCK) as child:
        assert any('ready' in ln for ln in child.tail), list(child.tail)
        child.interrupt()
        code = child.wait(0.5)
    assert code == -9 and child.killed
    assert 0.5 <= child.stop_s < 5.0
    out = capsys.readouterr().out
    assert 'stuck did not exit' in out and 'killed (SIGKILL)' in out
    # the stack of the hung thread, printed by the child itself
    assert 'teardown_that_hangs' in out, out


def test_a_child_that_stops_in_time_reports_its_stop_time():
    with started("import time; print('ready', flush=True); time.sleep(60)") as child:
        child.interrupt()
        code = child.wait(5.0)
    assert code != -9 and not child.killed
    assert 0.0 <= child.stop_s < 5.0


def test_a_quiet_child_that_fails_prints_why_once(capsys):
    code = ("import sys, time; print('ready', flush=True); time.sleep(0.2); "
            "print('the reason it failed', flush=True); sys.exit(1)")
    with started(code) as child:
        assert child.wait(5.0) == 1
        assert child.wait(5.0) == 1
    out = capsys.readouterr().out
    assert out.count('stuck exited 1; its last output:') == 1, out
    assert '| the reason it failed' in out, out


def test_a_clean_or_refused_exit_prints_nothing_more(capsys):
    for rc in (0, 2):
        with started("import sys; print('ready', flush=True); sys.exit(%d)" % rc) as child:
            assert child.wait(5.0) == rc
    assert 'its last output' not in capsys.readouterr().out
