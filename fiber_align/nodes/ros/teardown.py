# SPDX-License-Identifier: Apache-2.0
"""
The end of a node process (:func:`finish`): exit reports, close, acks, bounded teardown.

:func:`say` writes every line a node writes at its stop: a dead launcher's pipe ends none.
"""

import faulthandler
import json
import os
import sys
import time

#: Exit report prefix of the line ``FIBER_ALIGN_SENT {json}`` (bringup collects them).
SENT_PREFIX = 'FIBER_ALIGN_SENT '


def report_sent(node, counts):
    """Print the exit report: ``counts`` (topic -> messages published), one JSON line."""
    say(SENT_PREFIX + json.dumps({'node': node.get_fully_qualified_name(),
                                  'sent': dict(counts)}))


def say(line, stream=None):
    """
    Write one line to ``stream`` (``sys.stdout``); a reader that is gone ends nothing.

    A launcher killed with SIGKILL leaves its children's output pipes without a reader:
    a write raises ``BrokenPipeError``, which would end the stop before the nodes are
    closed (a driver's device left at its voltage). The stream is pointed at
    ``/dev/null`` instead, so the interpreter's own flush at exit cannot fail either.
    Return True if the line was written.
    """
    stream = sys.stdout if stream is None else stream
    try:
        print(line, file=stream, flush=True)
        return True
    except (OSError, ValueError):       # EPIPE, EIO of a closed terminal, a closed file
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, stream.fileno())
            os.close(null)
        except (OSError, ValueError):
            pass
        return False


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
    settle(nodes, ACK_S)
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


def settle(nodes, limit_s):
    """Wait up to ``limit_s`` (s) in all until each reliable publisher's samples are acked."""
    from rclpy.duration import Duration
    end = time.monotonic() + float(limit_s)
    for pub in [p for n in nodes for p in getattr(n, 'publishers', ())]:
        pub.wait_for_all_acked(Duration(seconds=max(0.0, end - time.monotonic())))


#: s: the longest a node process's teardown (nodes, contexts, DDS participants) may take
#: once its reports are out and its files closed: a node whose launcher was killed is
#: gone within 2 s (the lifeline's notice, the close, this), and well under bringup's and
#: launch's stop timeouts (about 5 s), so the process ends itself first
TEARDOWN_S = 1.0


def teardown_guard(limit_s, stop=None):
    """
    Return a started guard that ends the process if the teardown outlasts ``limit_s``.

    rcl's node teardown (``destroy_when_not_in_use``, the DDS participant's) has been
    seen to wait for seconds; the process has nothing left to save then. A timer thread
    prints one line naming the stall and exits with the process's code (:func:`exit_code`
    of ``stop``), without the interpreter's exit. A teardown that waits while it holds
    the GIL (rclpy's ``destroy_node`` does) stops that thread too; for that case
    ``faulthandler``'s watchdog, a C thread that needs no GIL, ends the process
    :data:`BACKSTOP_S` later with every thread's stack and exit code 1. Cancel the guard
    (:meth:`TeardownGuard.cancel`) when the teardown ended.
    """
    return TeardownGuard(limit_s, stop)


#: s: after the teardown guard's bound, the GIL-free backstop's (:func:`teardown_guard`)
BACKSTOP_S = 0.3


class TeardownGuard:
    """The two exits of :func:`teardown_guard`: its timer thread and the C backstop."""

    def __init__(self, limit_s, stop=None):
        """Start both; ``limit_s`` in s."""
        import threading
        self.limit_s = float(limit_s)
        self.stop = stop
        self.timer = threading.Timer(self.limit_s, self._abandon)
        self.timer.daemon = True
        self.timer.start()
        try:
            faulthandler.dump_traceback_later(self.limit_s + BACKSTOP_S, exit=True)
        except (OSError, ValueError, RuntimeError):     # no usable stderr
            pass

    def _abandon(self):
        code = self.stop.exit_code(0) if self.stop is not None else 0
        try:
            say('teardown: the middleware did not end within %g s; exiting %d without it'
                % (self.limit_s, code), sys.stderr)
        finally:
            os._exit(code)

    def cancel(self):
        """Disarm both exits (the teardown ended)."""
        self.timer.cancel()
        faulthandler.cancel_dump_traceback_later()


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
