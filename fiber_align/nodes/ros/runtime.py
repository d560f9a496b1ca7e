# SPDX-License-Identifier: Apache-2.0
"""
Runtime of a fiber_align node process: init, signals, executor, spin, exit code.

Every executable's ``main()`` is :func:`run_node`, the demo_nodes_py idiom (:func:`init`,
:func:`spin`, :func:`~fiber_align.nodes.ros.teardown.finish`; bad parameters:
:func:`refuse`, one line, exit 2). The process's scheduling is
:mod:`fiber_align.nodes.ros.scheduling`, its exit reports and bounded teardown
:mod:`fiber_align.nodes.ros.teardown`.
"""

import faulthandler
import signal
import sys

from rclpy.exceptions import ParameterException

from fiber_align import lifeline
from fiber_align.config import ConfigError
from fiber_align.lifeline import say, StopFlag
from fiber_align.nodes.ros.scheduling import (
    CpuLatencyRequest, node_priority, set_realtime_priority)
from fiber_align.nodes.ros.teardown import drain, finish

#: The signals that stop a node in order: Ctrl-C, ``kill`` and launch's escalation, and
#: the hang-up of a closed or crashed terminal (sent to the launcher's whole group).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: The signal that makes a node print every thread's Python stack (``faulthandler``),
#: even inside a C call that holds the interpreter: ``bringup`` sends it to a process
#: that overran its stop, before SIGKILL, so the log says where it was stuck.
STACKS_SIGNAL = signal.SIGUSR1


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


#: Errors of a node's construction that are bad input: one line, exit code 2.
NODE_ERRORS = (ConfigError, ParameterException, ValueError, TypeError, KeyError)


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


#: s: the longest a realtime process's other Python threads keep the control thread
#: waiting for the GIL (``sys.setswitchinterval``; Python's default 5 ms)
GIL_SWITCH_S = 0.0002


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
    if priority:
        # a thread of Python work beside the control thread (a bag's close, a snapshot)
        # holds the GIL until the interval ends: 5 ms by default, five periods
        sys.setswitchinterval(GIL_SWITCH_S)
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
