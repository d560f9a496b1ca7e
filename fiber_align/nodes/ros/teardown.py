# SPDX-License-Identifier: Apache-2.0
"""
The end of a node process (:func:`finish`): exit reports, close, acks, bounded teardown.

Every line a node writes at its stop goes through :func:`fiber_align.lifeline.say` (a
dead launcher's pipe ends none); the bound is :func:`fiber_align.lifeline.teardown_guard`.
"""

import json
import sys
import time

from fiber_align.lifeline import parent_gone, say, TEARDOWN_S, teardown_guard

#: Exit report prefix of the line ``FIBER_ALIGN_SENT {json}`` (bringup collects them).
SENT_PREFIX = 'FIBER_ALIGN_SENT '


def report_sent(node, counts):
    """Print the exit report: ``counts`` (topic -> messages published), one JSON line."""
    say(SENT_PREFIX + json.dumps({'node': node.get_fully_qualified_name(),
                                  'sent': dict(counts)}))


def finish(nodes, stop=None, limit_s=None):
    """
    Print each node's exit report, close it, destroy the nodes, shut rclpy down.

    The contexts are destroyed and the frozen objects collected here too, so the
    middleware's teardown (the DDS participants) runs under this process's handlers:
    in the interpreter's exit SIGINT and SIGTERM have their default action again, and a
    second signal there would kill the process (exit -2, no bag report, no clean code).
    Every node with a ``close()`` (a recorder's bag finalised, a driver's device ramped
    to its safe voltage and shut) is closed before any node is destroyed, and the
    teardown is bounded (:func:`teardown_guard`): once the reports are out, the bag is
    whole and the devices safe, a middleware teardown that hangs ends the process with
    its code and a line that says so, instead of the launcher's SIGKILL.

    :param stop: the process's :class:`StopFlag` (its exit code if the guard fires).
    :param limit_s: the teardown's bound (s); ``None``: :data:`TEARDOWN_S`.
    """
    import gc

    import rclpy
    nodes = [n for n in (nodes if isinstance(nodes, (list, tuple)) else [nodes])
             if n is not None]
    for node in nodes:
        if hasattr(node, 'sent_counts'):
            report_sent(node, node.sent_counts())
    for node in nodes:
        close = getattr(node, 'close', None)
        if callable(close):
            close()
    settle(nodes, ACK_GONE_S if parent_gone() else ACK_S)
    guard = teardown_guard(TEARDOWN_S if limit_s is None else limit_s, stop)
    try:
        contexts = []
        for node in nodes:
            if node.context not in contexts:
                contexts.append(node.context)
            node.destroy_node()
        rclpy.try_shutdown()
        for context in contexts:
            context.try_shutdown()
            context.destroy()
        gc.unfreeze()
        gc.collect()
    finally:
        guard.cancel()


#: s: the longest a process waits for its readers' acknowledgements (:func:`settle`): a
#: reliable writer destroyed first takes its unacknowledged samples with it
ACK_S = 0.5
#: s: the same once the launcher is gone (SIGKILL): the readers an acknowledgement would
#: come from are stopping too (docs/ros_interface.md, "A bag is readable after any stop")
ACK_GONE_S = 0.1


def settle(nodes, limit_s):
    """Wait up to ``limit_s`` (s) in all until each reliable publisher's samples are acked."""
    from rclpy.duration import Duration
    end = time.monotonic() + float(limit_s)
    for pub in [p for n in nodes for p in getattr(n, 'publishers', ())]:
        pub.wait_for_all_acked(Duration(seconds=max(0.0, end - time.monotonic())))


def drain(executor, timeout_s):
    """
    Wait up to ``timeout_s`` (s) for the callbacks a multi-threaded executor has in flight.

    rclpy's ``Executor.shutdown`` destroys the executor's guard condition without waiting
    for them (its wait is skipped once the shutdown flag is set), and a callback still
    running then fails on it; its task's error is printed at the interpreter's exit
    (``The following exception was never retrieved: cannot use Destroyable ...``). Call
    it once the spin loop ended (nothing new is started). An error of a callback that
    ends here is printed as one line.
    """
    end = time.monotonic() + float(timeout_s)
    for task in list(getattr(executor, '_futures', ())):
        while not task.done() and time.monotonic() < end:
            time.sleep(0.005)
        exc = task.exception() if task.done() else None     # fetched: not printed at exit
        if exc is not None:
            say('stop: a callback failed: %s: %s' % (type(exc).__name__, exc), sys.stderr)


def spin_until_quiet(executor, count, quiet_s, limit_s):
    """
    Run callbacks until ``count()`` has not changed for ``quiet_s`` s (a node's last input).

    :param count: callable, the messages taken so far.
    :param limit_s: the longest it runs (s), or a callable asked on every turn (a parent
        that died wants the process gone sooner).
    """
    import rclpy
    bound = limit_s if callable(limit_s) else (lambda: limit_s)
    t0 = quiet_since = time.monotonic()
    last = count()
    while rclpy.ok() and time.monotonic() - t0 < bound():
        executor.spin_once(timeout_sec=0.02)
        now_count = count()
        if now_count != last:
            last, quiet_since = now_count, time.monotonic()
        elif time.monotonic() - quiet_since >= quiet_s:
            break
