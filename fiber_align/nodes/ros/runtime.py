# SPDX-License-Identifier: Apache-2.0
"""
Runtime of a fiber_align node process: init, executor, realtime priority, spin, exit.

Every executable's ``main()`` is :func:`run_node`, the demo_nodes_py idiom (:func:`init`,
:func:`spin`, :func:`finish`; bad parameters: :func:`refuse`, one line, exit 2).
"""

import faulthandler
import json
import os
import signal
import sys

from rclpy.exceptions import ParameterException

from fiber_align import lifeline
from fiber_align.config import ConfigError

#: The signals that stop a node in order: Ctrl-C, ``kill`` and launch's escalation, and
#: the hang-up of a closed or crashed terminal (sent to the launcher's whole group).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: The signal that makes a node print every thread's Python stack (``faulthandler``),
#: even inside a C call that holds the interpreter: ``bringup`` sends it to a process
#: that overran its stop, before SIGKILL, so the log says where it was stuck.
STACKS_SIGNAL = signal.SIGUSR1
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


def make_executor(realtime=False, threads=1):
    """
    Return the executor for a node process.

    ``threads`` > 1: a ``MultiThreadedExecutor`` (a node that waits on services from its
    own callbacks); realtime: rclpy's C++ ``EventsExecutor`` when this rclpy has it (far
    less overhead per callback); else the ``SingleThreadedExecutor``.
    """
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
    if threads > 1:
        return MultiThreadedExecutor(num_threads=threads)
    if realtime:
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except ImportError:
            pass
    return SingleThreadedExecutor()


def set_realtime_priority(priority, lock=False):
    """
    Run this process's threads (the executor's and the DDS threads) under ``SCHED_FIFO``.

    Threads started afterwards inherit it (as ros2_control's controller manager does).
    Without the right to (not root, no ``rtprio`` limit in
    ``/etc/security/limits.conf``) it changes nothing and says why.

    :param priority: 1..99 (``SCHED_FIFO``), 0: leave the normal policy.
    :param lock: also lock the process's memory (:func:`lock_memory`) when the policy
        was set.
    :returns: a short text for the log and ``/diagnostics`` (``SCHED_FIFO 50``, or
        ``SCHED_OTHER (...)`` with the reason).
    """
    import os
    priority = int(priority)
    if priority <= 0:
        return 'SCHED_OTHER (realtime_priority 0)'
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as exc:
        return 'SCHED_OTHER (SCHED_FIFO %d refused: %s)' % (priority, exc)
    # the other threads too: the DDS threads would queue behind busy normal processes
    for tid in os.listdir('/proc/self/task'):
        try:
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, ValueError):
            pass
    if not lock:
        return 'SCHED_FIFO %d' % priority
    return 'SCHED_FIFO %d, %s' % (priority, 'memory locked' if lock_memory()
                                  else 'memory not locked (mlockall refused)')


def lock_memory():
    """
    Lock the process's pages in RAM (``mlockall``), as realtime ROS 2 loops do.

    The cost is resident memory (every mapped page, each DDS thread's stack). Needs root
    or a large enough ``memlock`` limit; returns False (nothing changed) when refused.
    """
    import ctypes
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.mlockall(1 | 2) == 0        # MCL_CURRENT | MCL_FUTURE
    except (OSError, AttributeError):
        return False


class CpuLatencyRequest:
    """
    A PM QoS request of 0 us on ``/dev/cpu_dma_latency``: idle CPUs poll, never halt.

    The kernel keeps every CPU out of the idle states slower to leave than the smallest
    request while the file stays open, and drops the request when it is closed (at the
    latest when the process ends, however it ends). A halted CPU wakes late for a timer,
    and a halted virtual CPU goes back to its host, which may keep it for milliseconds;
    a polling one answers at once. The cost is power (the CPUs never sleep), not CPU
    time of any process. Needs root (the file is root's alone).
    """

    PATH = '/dev/cpu_dma_latency'

    def __init__(self):
        """Open nothing yet (:meth:`hold`)."""
        self._fd = None

    def hold(self):
        """
        Make the request; return a short text for the log and ``/diagnostics``.

        ``CPUs held awake`` when the kernel took it, else ``CPUs not held awake
        (cpu_dma_latency refused: ...)`` with the reason; nothing changes then.
        """
        import os
        import struct
        if self._fd is not None:
            return 'CPUs held awake'
        fd = None
        try:
            fd = os.open(self.PATH, os.O_WRONLY | os.O_CLOEXEC)
            os.write(fd, struct.pack('i', 0))
        except OSError as exc:
            if fd is not None:
                os.close(fd)
            return 'CPUs not held awake (cpu_dma_latency refused: %s)' % exc.strerror
        self._fd = fd
        return 'CPUs held awake'

    @property
    def held(self):
        """Return True while the request is in force."""
        return self._fd is not None

    def release(self):
        """End the request (idempotent)."""
        import os
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)


#: Errors of a node's construction that are bad input: one line, exit code 2.
NODE_ERRORS = (ConfigError, ParameterException, ValueError, TypeError, KeyError)


class StopFlag:
    """
    Set by a signal handler, read by a loop: a plain attribute, no lock.

    A handler runs between two bytecodes of whatever it interrupted; an
    ``threading.Event.set`` there takes the event's non-reentrant lock, so a second
    signal arriving inside the first handler would deadlock the process.
    """

    __slots__ = ('_set', 'again')

    def __init__(self):
        """Start unset."""
        self._set = False
        #: the number of a signal that came after the flag was set (0: none)
        self.again = 0

    def set(self):
        """Set the flag (safe in a signal handler, any number of times, nested)."""
        self._set = True

    def note(self, signum):
        """Set the flag for signal ``signum``; one after the first is kept in ``again``."""
        if self._set:
            self.again = int(signum)
        self._set = True

    def exit_code(self, code=0):
        """
        Return ``code``, or ``128 + signal`` when a second signal came during the stop.

        The first SIGINT or SIGTERM is the ordinary request to stop: the node stops in
        order and exits ``code`` (0: ``ros2 launch`` reports it finished cleanly). A
        second one while stopping does not cut the stop short (the recorder still
        finalises its bag) but is reported the shell's way, as a process ended by that
        signal: 130 for SIGINT, 143 for SIGTERM.
        """
        return 128 + self.again if self.again else code

    def is_set(self):
        """Return True once set."""
        return self._set

    def clear(self):
        """Unset the flag."""
        self._set = False


def init(args=None):
    """
    Initialise rclpy with this process's own stop-signal handlers; return the flag.

    rclpy's handlers shut the context down at once, while a callback may still publish
    on it. Here a signal only sets the returned flag: the spin loop ends, then the nodes
    are destroyed and the context shut down in order; a second signal during that stop
    changes only the exit code (:meth:`StopFlag.exit_code`). The handlers are installed
    whatever the inherited disposition (a background job inherits SIGINT ignored), for
    :data:`STOP_SIGNALS`. The process stops the same way when the process that started
    it dies (:func:`fiber_align.lifeline.watch_parent`: ``SIGTERM``).
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    stop = StopFlag()

    def on_signal(signum, frame):
        stop.note(signum)
    for signum in STOP_SIGNALS:
        signal.signal(signum, on_signal)
    faulthandler.register(STACKS_SIGNAL, all_threads=True)
    lifeline.watch_parent(lifeline.PARENT_PID, signal.SIGTERM)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    return stop


def refuse(name, exc):
    """Print one line for a node that cannot start (bad input); return exit code 2."""
    say('%s: error: %s' % (name, exc), sys.stderr)
    return 2


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


def exit_code(stop, code=0):
    """
    Return the process's exit code (:meth:`StopFlag.exit_code`); ignore signals from now.

    Called once the nodes are finished: what is left is the interpreter's exit, where a
    signal's default action would end the process by that signal instead of ``code``.
    """
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
    return stop.exit_code(code)


#: Modules imported on first use deep inside a control period, each once per process:
#: numpy's percentile imports ``numpy.ma`` (a first ``/diagnostics`` report took 6-8 ms),
#: the in-process recorder's first message of a topic imports ``rosidl_runtime_py``,
#: rclpy's serialisation and rosbags' serialiser (a tick of 3-15 ms). Imported before the
#: spin instead.
WARM_IMPORTS = ('numpy.ma', 'rosidl_runtime_py.utilities', 'rclpy.serialization',
                'rosbags.serde.primitives')


def warm_imports(names=WARM_IMPORTS):
    """Import ``names`` now (those missing from this install are skipped)."""
    import importlib
    for name in names:
        try:
            importlib.import_module(name)
        except ImportError:
            pass


def spin(nodes, realtime=False, priority=0, stop=None, threads=1, then=None):
    """
    Spin ``nodes`` (one node or a list) until the context shuts down.

    Ctrl-C, SIGTERM or ``rclpy.shutdown`` end it (the loop wakes every 0.1 s). The
    objects built so far are frozen out of the garbage collector's reach first
    (``gc.freeze``), so a full collection cannot stall a control period.

    :param realtime: choose the events executor when available (:func:`make_executor`).
    :param priority: ``SCHED_FIFO`` priority of the executor thread
        (:func:`set_realtime_priority`; 0: normal).
    :param stop: the :class:`StopFlag` of :func:`init`; set, it ends the spin.
    :param threads: executor threads (:func:`make_executor`); :param then: called with
        the executor once the loop ended (e.g. a drain).
    """
    import gc
    nodes = list(nodes) if isinstance(nodes, (list, tuple)) else [nodes]
    # lockstep runs as fast as the messages go: a realtime policy would starve the graph
    priority = priority if realtime else 0
    lock = any(n.has_parameter('lock_memory') and n.get_parameter('lock_memory').value
               for n in nodes)
    sched = set_realtime_priority(priority, lock)
    awake = CpuLatencyRequest()
    if sched.startswith('SCHED_FIFO') and any(
            n.has_parameter('cpu_idle_poll') and n.get_parameter('cpu_idle_poll').value
            for n in nodes):
        sched += ', ' + awake.hold()
    for node in nodes:
        if priority:
            lg = node.get_logger()
            ok = sched.startswith('SCHED_FIFO') and 'refused' not in sched
            (lg.info if ok else lg.warn)('scheduling: %s' % sched)
        health = getattr(node, 'health', None)
        if health is not None:
            health.set_values(scheduling=sched)
    executor = make_executor(realtime, threads)
    for node in nodes:
        executor.add_node(node)
    warm_imports()
    gc.collect()
    gc.freeze()
    try:
        while executor.context.ok() and not (stop is not None and stop.is_set()):
            executor.spin_once(timeout_sec=0.1)
        if then is not None:
            then(executor)
    finally:
        for node in nodes:
            try:
                executor.remove_node(node)
            except Exception:  # noqa: BLE001 - context already shut down
                pass
        drain(executor, 1.0)
        executor.shutdown(timeout_sec=1.0)
        awake.release()


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
    import time
    end = time.monotonic() + float(timeout_s)
    for task in list(getattr(executor, '_futures', ())):
        while not task.done() and time.monotonic() < end:
            time.sleep(0.005)
        exc = task.exception() if task.done() else None     # fetched: not printed at exit
        if exc is not None:
            say('stop: a callback failed: %s: %s' % (type(exc).__name__, exc), sys.stderr)


def run_node(factory, name, args=None, realtime=None, threads=1, then=None):
    """
    Run one node in this process: the demo_nodes_py ``main()`` (init, spin, finish).

    :param factory: returns the node (called after :func:`init`).
    :param name: the node's name for the one-line refusal of bad parameters.
    :param realtime: ``node -> bool``, spin with the realtime executor (``None``: the
        node's ``sync_mode`` parameter is ``realtime``).
    :param threads: executor threads (:func:`make_executor`).
    :param then: ``(executor, node)`` called once the spin ended (:func:`spin`).
    :returns: the exit code: 0, 2 for bad parameters, 130 (143) when a second SIGINT
        (SIGTERM) came during the stop (:meth:`StopFlag.exit_code`).
    """
    from rclpy.executors import ExternalShutdownException
    stop = init(args)
    node = None
    try:
        node = factory()
        rt = realtime(node) if realtime is not None else \
            node.get_parameter('sync_mode').value == 'realtime'
        spin(node, realtime=rt, priority=node_priority(node), stop=stop, threads=threads,
             then=None if then is None else (lambda executor: then(executor, node)))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except NODE_ERRORS as exc:
        return refuse(name, exc)
    finally:
        finish(node, stop)
    return exit_code(stop)


def node_priority(nodes):
    """Return the largest ``realtime_priority`` parameter of ``nodes`` (0 if none)."""
    nodes = nodes if isinstance(nodes, (list, tuple)) else [nodes]
    return max([int(n.get_parameter('realtime_priority').value) for n in nodes
                if n.has_parameter('realtime_priority')], default=0)
