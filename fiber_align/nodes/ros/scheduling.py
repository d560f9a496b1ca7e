# SPDX-License-Identifier: Apache-2.0
"""
The scheduling of a realtime node process: SCHED_FIFO, locked memory, CPUs held awake.

:func:`set_realtime_priority` (with :func:`lock_memory`) and :class:`CpuLatencyRequest`
are what :func:`fiber_align.nodes.ros.runtime.spin` applies before it spins a realtime
process; :func:`node_priority` reads the nodes' ``realtime_priority`` (1..99; 0: none).
"""


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


def node_priority(nodes):
    """Return the largest ``realtime_priority`` parameter of ``nodes`` (0 if none)."""
    nodes = nodes if isinstance(nodes, (list, tuple)) else [nodes]
    return max([int(n.get_parameter('realtime_priority').value) for n in nodes
                if n.has_parameter('realtime_priority')], default=0)
