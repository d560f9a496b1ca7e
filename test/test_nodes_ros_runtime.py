# SPDX-License-Identifier: Apache-2.0
"""The nodes' signal handling (``nodes.ros.runtime``): a nested signal cannot deadlock a stop."""

import subprocess
import sys
import textwrap
import time

import pytest

pytestmark = pytest.mark.ros


#: A child that takes SIGTERM with a handler calling ``stop.set()``, and sends itself a
#: second SIGTERM while the first handler is inside ``set`` (where ``threading.Event``
#: holds its lock: at ``notify_all``): as a parent-death SIGTERM that comes twice.
CHILD = textwrap.dedent('''
    import os, signal, sys, threading
    from fiber_align.lifeline import StopFlag
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


#: A process whose node's teardown never ends (as rcl's ``destroy_when_not_in_use`` was
#: seen to): its bag-like file must be closed first, and the guard must end the process
#: with its exit code and a line that names the stall.
HANGING = textwrap.dedent('''
    import signal, sys, threading, time
    from fiber_align.lifeline import StopFlag
    from fiber_align.nodes.ros.teardown import finish

    class Node:
        context = None

        def close(self):
            print('closed', flush=True)

        def destroy_node(self):
            if sys.argv[1].startswith('gil'):   # waits in C holding the GIL, as rclpy's does
                import ctypes
                ctypes.PyDLL(None).sleep(20)
            threading.Event().wait()        # never returns

    stop = StopFlag()
    stop.note(signal.SIGINT)
    if sys.argv[1].endswith('twice'):
        stop.note(signal.SIGINT)
    t0 = time.monotonic()
    try:
        finish([Node()], stop, limit_s=0.5)
    finally:
        print('not reached', time.monotonic() - t0, flush=True)
''')


@pytest.mark.parametrize('how, code', [('once', 0), ('twice', 130)])
def test_a_teardown_that_hangs_ends_the_process_with_its_code(how, code):
    out = subprocess.run([sys.executable, '-c', HANGING, how], capture_output=True,
                         text=True, timeout=30)
    assert out.returncode == code, (out.stdout, out.stderr)
    assert out.stdout.splitlines() == ['closed']
    assert 'teardown: the middleware did not end within 0.5 s; exiting %d' % code \
        in out.stderr


#: A node process whose launcher was killed: its output pipes have no reader; its exit
#: report and the teardown guard's line meet a broken pipe.
READER_GONE = textwrap.dedent('''
    import signal, sys, threading
    from fiber_align.lifeline import StopFlag
    from fiber_align.nodes.ros.teardown import finish

    class Node:
        context = None

        def get_fully_qualified_name(self):
            return '/node'

        def sent_counts(self):
            return {'/topic': 1}

        def close(self):
            with open(sys.argv[1], 'w') as f:
                f.write('closed')

        def destroy_node(self):
            threading.Event().wait()        # never returns

    stop = StopFlag()
    stop.note(signal.SIGTERM)
    finish([Node()], stop, limit_s=0.5)
''')


def test_a_stop_whose_output_has_no_reader_closes_the_nodes_and_exits_0(tmp_path):
    closed = tmp_path / 'closed'
    proc = subprocess.Popen([sys.executable, '-c', READER_GONE, str(closed)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    proc.stderr.close()
    try:
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
        proc.wait()
    assert closed.read_text() == 'closed'


@pytest.mark.parametrize('how, code', [('gil', 0), ('gil-twice', 130)])
def test_a_teardown_that_hangs_holding_the_gil_ends_the_process_with_its_code(how, code):
    """The timer thread cannot run then; the GIL-free backstop ends it, with every stack."""
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, '-c', HANGING, how], capture_output=True,
                         text=True, timeout=10)
    took = time.monotonic() - t0
    assert out.returncode == code, (out.stdout, out.stderr)
    assert out.stdout.splitlines() == ['closed']
    assert 'did not end within 0.8 s and holds the GIL; exiting %d' % code in out.stderr
    assert 'destroy_node' in out.stderr, out.stderr      # where it hung, for the log
    assert took < 5.0, took


#: What a realtime process does for the first time inside a control period: a
#: ``/diagnostics`` report's percentiles and the in-process recorder's first CDR.
FIRST_USE = textwrap.dedent('''
    import sys
    import numpy as np
    from fiber_align.control.cycle import CycleStats
    from fiber_align.nodes.ros.runtime import warm_imports
    from rosbags.typesys import get_typestore, Stores
    from std_msgs.msg import Float64
    from fiber_align.nodes.ros.cdr import encoder
    from rclpy.type_support import check_for_type_support
    store = get_typestore(Stores.ROS2_JAZZY)     # the recorder's, made when it starts
    check_for_type_support(Float64)              # as the publisher of the topic did
    if sys.argv[1] == 'warm':
        warm_imports()
    before = set(sys.modules)
    stats = CycleStats(1000.0)
    stats.window(0)
    for k in range(10):
        stats.record(1e-4 * k, k)
    stats.window(10 ** 7)
    encoder(store, 'std_msgs/msg/Float64', Float64)(Float64(data=1.0))   # checked once
    print(sorted(set(sys.modules) - before))
''')


def test_warm_imports_leave_nothing_to_import_inside_a_control_period():
    def new_modules(how):
        out = subprocess.run([sys.executable, '-c', FIRST_USE, how], capture_output=True,
                             text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()
    assert 'numpy.ma' in new_modules('cold')      # what the warm-up is for
    assert new_modules('warm') == '[]'


#: A node whose callbacks are still queued in a multi-threaded executor when it stops.
BUSY_AT_STOP = textwrap.dedent('''
    import threading, time
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.node import Node
    from fiber_align.nodes.ros import runtime, teardown
    stop = runtime.init([])
    node = Node('busy_at_stop')
    group = ReentrantCallbackGroup()        # more ready than threads: a queue in the pool
    for _ in range(4):
        node.create_timer(0.02, lambda: time.sleep(0.1), callback_group=group)
    threading.Timer(0.5, stop.set).start()
    runtime.spin(node, stop=stop, threads=2)
    teardown.finish([node], stop)
    print('stopped')
''')


def test_callbacks_in_flight_at_the_stop_end_before_the_executor_is_destroyed():
    """No ``exception was never retrieved`` at exit (rclpy's shutdown does not wait)."""
    outs = []
    for _ in range(3):
        out = subprocess.run([sys.executable, '-c', BUSY_AT_STOP], capture_output=True,
                             text=True, timeout=60)
        assert out.returncode == 0 and 'stopped' in out.stdout, out.stderr
        outs.append(out.stderr)
    assert not any('never retrieved' in e or 'Destroyable' in e for e in outs), outs
