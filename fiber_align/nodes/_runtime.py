# SPDX-License-Identifier: Apache-2.0
"""
Runtime of a fiber_align node process: init, executor, realtime priority, spin, exit.

Every executable's ``main()`` is the demo_nodes_py idiom built from these: :func:`init`
(rclpy with the process's own SIGINT/SIGTERM handlers), :func:`spin`, :func:`refuse` for
bad parameters (one line, exit 2) and :func:`finish`; :func:`run_node` is that idiom for
a process of one node.
"""

import json
import sys

from rclpy.exceptions import ParameterException

from fiber_align.config import ConfigError

#: Exit report prefix: each node prints one line ``FIBER_ALIGN_SENT {json}`` on exit with
#: the number of messages it published per topic; bringup collects them.
SENT_PREFIX = 'FIBER_ALIGN_SENT '


def report_sent(node, counts):
    """
    Print the exit report of published message counts (one JSON line on stdout).

    :param counts: topic name -> number of messages published.
    """
    line = SENT_PREFIX + json.dumps({'node': node.get_fully_qualified_name(),
                                     'sent': dict(counts)})
    print(line, flush=True)
    sys.stdout.flush()


def make_executor(realtime=False):
    """
    Return the executor for a node process.

    Realtime processes run on rclpy's C++ ``EventsExecutor`` when this rclpy has it (far
    less overhead per callback than the Python wait-set loop of the
    ``SingleThreadedExecutor``); others use the ``SingleThreadedExecutor``.
    """
    from rclpy.executors import SingleThreadedExecutor
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

    Threads started afterwards inherit it. This is what ros2_control's
    controller manager does: a 1 kHz loop on a general-purpose OS keeps its period
    against other load only at a realtime priority. Without the right to (not root,
    no ``rtprio`` limit, e.g. ``@realtime - rtprio 98`` in
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
    # the process's other threads too: the DDS threads that receive the messages of a
    # multi-process graph would otherwise queue behind every busy normal process
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

    A page fault on a page the kernel had reclaimed can stall a tick by milliseconds
    where memory is tight (here, 24 GB without swap, it made no measurable difference;
    ``lock_memory`` in config/fiber_align.yaml is off). The cost is resident memory: every
    mapped page, the 8 MB stack of each DDS thread too (control_graph 142 -> 460 MB).
    Needs root or a large enough ``memlock`` limit; where the present memory is over the
    limit the call fails and changes nothing (returns False).
    """
    import ctypes
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.mlockall(1 | 2) == 0        # MCL_CURRENT | MCL_FUTURE
    except (OSError, AttributeError):
        return False


#: Errors of a node's construction that are bad input (a parameter of the wrong type or
#: out of its range, a broken config): one line and exit code 2, no traceback.
NODE_ERRORS = (ConfigError, ParameterException, ValueError, TypeError, KeyError)


class StopFlag:
    """
    Set by a signal handler, read by a loop: a plain attribute, no lock.

    A handler runs in the main thread between two bytecodes of whatever it interrupted.
    ``threading.Event.set`` takes the event's (non-reentrant) lock, so a second signal
    arriving while the first handler is inside it deadlocks the process: seen as a
    ``control_graph`` that outlived a SIGKILLed ``bringup`` (its parent-death SIGTERM
    comes twice), its main thread blocked in the handler's ``lock.acquire``.
    """

    __slots__ = ('_set',)

    def __init__(self):
        """Start unset."""
        self._set = False

    def set(self):
        """Set the flag (safe in a signal handler, any number of times, nested)."""
        self._set = True

    def is_set(self):
        """Return True once set."""
        return self._set

    def clear(self):
        """Unset the flag."""
        self._set = False


def init(args=None):
    """
    Initialise rclpy with this process's own SIGINT and SIGTERM handlers; return the flag.

    rclpy's handlers shut the context down at once, while the executor may still run a
    callback that then publishes on a dead context (``[FATAL] Exception in 'timers'
    callback`` at an ordinary stop). Here a signal only sets the returned event; the spin
    loop ends, and the nodes are destroyed and the context shut down in order. The
    handlers are installed whatever the inherited disposition (a background job of a
    non-interactive shell inherits SIGINT ignored).
    """
    import signal

    import rclpy
    from rclpy.signals import SignalHandlerOptions
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopFlag()

    def on_signal(signum, frame):
        stop.set()
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return stop


def refuse(name, exc):
    """Print one line for a node that cannot start (bad input); return exit code 2."""
    print('%s: error: %s' % (name, exc), file=sys.stderr, flush=True)
    return 2


def finish(nodes):
    """Print each node's exit report, destroy the nodes, shut rclpy down (idempotent)."""
    import rclpy
    for node in nodes if isinstance(nodes, (list, tuple)) else [nodes]:
        if node is None:
            continue
        if hasattr(node, 'sent_counts'):
            report_sent(node, node.sent_counts())
        node.destroy_node()
    rclpy.try_shutdown()


def spin(nodes, realtime=False, priority=0, stop=None):
    """
    Spin ``nodes`` (one node or a list) until the context shuts down.

    Ctrl-C, SIGTERM or ``rclpy.shutdown`` end it; the loop wakes at least every 0.1 s
    (wall) to notice a shutdown. Before spinning, the objects built so far are frozen
    out of the garbage collector's reach (``gc.freeze``): a full collection then walks
    only what the loop allocates, so it cannot stall a control period.

    :param realtime: choose the events executor when available (:func:`make_executor`).
    :param priority: ``SCHED_FIFO`` priority of the executor thread
        (:func:`set_realtime_priority`; 0: normal).
    :param stop: the :class:`StopFlag` of :func:`init`; set, it ends the spin.
    """
    import gc
    nodes = list(nodes) if isinstance(nodes, (list, tuple)) else [nodes]
    # lockstep runs as fast as the messages go: a realtime policy there could only
    # starve the other processes of the graph
    priority = priority if realtime else 0
    lock = any(n.has_parameter('lock_memory') and n.get_parameter('lock_memory').value
               for n in nodes)
    sched = set_realtime_priority(priority, lock)
    for node in nodes:
        if priority:
            log = node.get_logger().info if sched.startswith('SCHED_FIFO') \
                else node.get_logger().warn
            log('scheduling: %s' % sched)
        health = getattr(node, 'health', None)
        if health is not None:
            health.set_values(scheduling=sched)
    executor = make_executor(realtime)
    for node in nodes:
        executor.add_node(node)
    gc.collect()
    gc.freeze()
    try:
        while executor.context.ok() and not (stop is not None and stop.is_set()):
            executor.spin_once(timeout_sec=0.1)
    finally:
        for node in nodes:
            try:
                executor.remove_node(node)
            except Exception:  # noqa: BLE001 - context already shut down
                pass
        executor.shutdown(timeout_sec=1.0)


def run_node(factory, name, args=None, realtime=None):
    """
    Run one node in this process: the demo_nodes_py ``main()`` (init, spin, finish).

    :param factory: returns the node (called after :func:`init`).
    :param name: the node's name for the one-line refusal of bad parameters.
    :param realtime: ``node -> bool``, spin with the realtime executor (``None``: the
        node's ``sync_mode`` parameter is ``realtime``).
    :returns: the exit code: 0, or 2 for bad parameters.
    """
    from rclpy.executors import ExternalShutdownException
    stop = init(args)
    node = None
    try:
        node = factory()
        rt = realtime(node) if realtime is not None else \
            node.get_parameter('sync_mode').value == 'realtime'
        spin(node, realtime=rt, priority=node_priority(node), stop=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except NODE_ERRORS as exc:
        return refuse(name, exc)
    finally:
        finish(node)
    return 0


def node_priority(nodes):
    """Return the largest ``realtime_priority`` parameter of ``nodes`` (0 if none)."""
    out = 0
    for node in nodes if isinstance(nodes, (list, tuple)) else [nodes]:
        if node.has_parameter('realtime_priority'):
            out = max(out, int(node.get_parameter('realtime_priority').value))
    return out


def guard_change_state(node):
    """
    Make a lifecycle node's ``~/change_state`` refuse a transition its state does not offer.

    rclpy's handler (``LifecycleNodeMixin.__on_change_state`` -> ``__change_state``) hands
    the requested id straight to ``trigger_transition_by_id``, which raises ``RCLError``
    ("Transition is not registered") for an id that does not start from the current
    state, e.g. ``configure`` (1) while active; the exception leaves the service callback,
    the executor re-raises it and the process dies. This wraps the service's callback
    (the executors call ``Service.callback``): an unavailable id or label is answered with
    ``success`` false, a WARN in the log and on ``/diagnostics`` (``node.health``) and a
    count in ``node.refused_transitions``; an available one goes to rclpy unchanged.
    """
    srv = getattr(node, '_service_change_state', None)
    if srv is None:
        return
    inner = srv.callback

    def change_state(request, response):
        t = request.transition
        try:
            state = node._state_machine.current_state[1]
            offered = [(i, lbl) for i, lbl, *_ in node._state_machine.available_transitions]
            ok = any((lbl == t.label) if t.label else (i == t.id) for i, lbl in offered)
            if ok:
                return inner(request, response)
            why = ('refused lifecycle transition %s: not available in state %s '
                   '(available: %s)' % (repr(t.label) if t.label else 'id %d' % t.id,
                                        state, ', '.join('%s (%d)' % (lbl, i)
                                                         for i, lbl in offered)))
        except Exception as exc:  # noqa: BLE001 - no request may kill the node
            why = 'lifecycle transition %d %r failed: %s' % (t.id, t.label, exc)
        node.refused_transitions += 1
        node.get_logger().warning(why)
        node.health.set_values(refused_transitions=node.refused_transitions)
        node.health.warn(why)
        response.success = False
        return response

    srv.callback = change_state
