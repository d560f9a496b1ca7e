# SPDX-License-Identifier: Apache-2.0
"""
A process of the package ends with the process that started it (its launcher).

Every executable calls :func:`watch_parent` where it starts (the node runtime's
``init``, ``bringup``, ``fiber-align emulate``). Once the parent process is gone (killed
with SIGKILL, an OOM kill, a closed terminal, ``ros2 launch`` ended by SIGTERM, which
leaves its processes behind), this process gets ``SIGTERM`` and stops exactly as on a
signal from outside: a node ends its spin and is destroyed in order, the recorder
finalises its bag.

The watch is a thread blocked on a pidfd of the parent (``pidfd_open``, Linux 5.3 and
Python 3.9), or polling ``getppid`` every :data:`POLL_S` s where that is missing.
``prctl(PR_SET_PDEATHSIG)`` is not used: the kernel sends that signal when the *thread*
that forked the child exits, so a launcher that starts its processes from a worker thread
(a thread pool, a GUI) would stop them while it runs on. The parent is the one this
module saw when it was first imported (:data:`PARENT_PID`); a parent that died before the
watch began (the child reparented already) is seen by comparing ``getppid()`` with it.
:class:`StopFlag` is what a stop signal sets, in a node process and in ``bringup`` alike.
"""

import os
import select
import signal
import threading
import time

#: The parent process of this process when the package was first imported.
PARENT_PID = os.getppid()
#: s: the period of the ``getppid`` poll where a pidfd cannot be had.
POLL_S = 0.1
#: ``(parent pid, signal)`` -> the watcher thread: one per process and parent.
_WATCHERS = {}


def parent_gone(parent_pid=PARENT_PID):
    """Return True once ``parent_pid`` is no longer this process's parent (it died)."""
    return os.getppid() != parent_pid


def watch_parent(parent_pid=PARENT_PID, signum=signal.SIGTERM):
    """
    Send ``signum`` to this process once ``parent_pid`` has exited; return the watcher.

    Idempotent per parent and signal. A parent already gone gets the signal sent at once
    (the handler the caller installed before runs; then no thread: returns ``None``).
    """
    key = (int(parent_pid), int(signum))
    if key in _WATCHERS:
        return _WATCHERS[key]
    try:
        fd = os.pidfd_open(key[0])
    except (AttributeError, OSError):        # no pidfd here, or the pid is gone
        fd = None
    if parent_gone(key[0]):      # died before the pidfd (its pid may be someone else's now)
        if fd is not None:
            os.close(fd)
        os.kill(os.getpid(), key[1])
        return None
    th = threading.Thread(target=_watch, args=(key[0], fd, key[1]),
                          name='lifeline', daemon=True)
    _WATCHERS[key] = th
    th.start()
    return th


def _watch(parent_pid, fd, signum):
    """Block until the parent exits, then signal this process (the watcher thread)."""
    if fd is not None:
        try:
            while not select.select([fd], [], [])[0]:     # readable: the parent exited
                pass
        finally:
            os.close(fd)
    while not parent_gone(parent_pid):  # also the pidfd's last look: the reparent is done
        time.sleep(POLL_S)
    os.kill(os.getpid(), signum)


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
