# SPDX-License-Identifier: Apache-2.0
"""The nodes' signal handling (``nodes.ros.runtime``): a nested signal cannot deadlock a stop."""

import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.ros


#: A child that takes SIGTERM with a handler calling ``stop.set()``, and sends itself a
#: second SIGTERM while the first handler is inside ``set`` (where ``threading.Event``
#: holds its lock: at ``notify_all``): as a parent-death SIGTERM that comes twice.
CHILD = textwrap.dedent('''
    import os, signal, sys, threading
    from fiber_align.nodes.ros.runtime import StopFlag
    stop = threading.Event() if sys.argv[1] == 'event' else StopFlag()
    inside = {'event': 'notify_all', 'flag': 'set'}[sys.argv[1]]
    fired = []

    def tracer(frame, event, arg):
        if event == 'call' and frame.f_code.co_name == inside and not fired:
            fired.append(1)
            os.kill(os.getpid(), signal.SIGTERM)

    signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
    sys.settrace(tracer)
    os.kill(os.getpid(), signal.SIGTERM)
    sys.settrace(None)
    print('stopped', stop.is_set(), len(fired))
''')


def _run(kind, timeout_s):
    try:
        out = subprocess.run([sys.executable, '-c', CHILD, kind], capture_output=True,
                             text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return None                     # deadlocked (the child is SIGKILLed)
    return out.stdout.strip()


def test_a_second_signal_inside_the_handler_still_stops():
    assert _run('flag', 30.0) == 'stopped True 1'


def test_the_harness_reproduces_the_deadlock_of_an_event():
    # why StopFlag exists: the same nested signal with threading.Event never returns
    assert _run('event', 5.0) is None
