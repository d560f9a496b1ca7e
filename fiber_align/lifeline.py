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
Its stop's lines go through :func:`say` (a reader that is gone ends nothing) and its
last part, the middleware's teardown, is bounded (:func:`teardown_guard`).
"""

import ctypes
import faulthandler
import os
import select
import signal
import sys
import threading
import time

#: The parent process of this process when the package was first imported.
PARENT_PID = os.getppid()
#: s: the period of the ``getppid`` poll where a pidfd cannot be had.
POLL_S = 0.1
#: s: a process still running this long after its parent ended is stuck in its stop (a
#: callback or a middleware call that does not return, so the stop flag is never read):
#: its threads' stacks go to stderr and it exits 1 (:func:`exit_later`, with or without
#: the GIL). Longer than any stop of the package's own (a node's is bounded to a few s,
#: ``bringup``'s by its children's 5 s stop timeouts and the bag's close).
STOP_BOUND_S = 30.0
#: ``(parent pid, signal)`` -> the watcher thread: one per process and parent.
_WATCHERS = {}
#: the armed backstops of a process whose parent ended (kept referenced until the exit)
_BACKSTOPS = []


def parent_gone(parent_pid=PARENT_PID):
    """Return True once ``parent_pid`` is no longer this process's parent (it died)."""
    return os.getppid() != parent_pid


def watch_parent(parent_pid=PARENT_PID, signum=signal.SIGTERM, bound_s=STOP_BOUND_S):
    """
    Send ``signum`` to this process once ``parent_pid`` has exited; return the watcher.

    Idempotent per parent and signal. A parent already gone gets the signal sent at once
    (the handler the caller installed before runs; then no thread: returns ``None``).
    Either way the process ends ``bound_s`` s after the signal if its stop has not
    (:func:`end_later`).
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
        signal_main(key[1])
        end_later(bound_s)
        return None
    th = threading.Thread(target=_watch, args=(key[0], fd, key[1], bound_s),
                          name='lifeline', daemon=True)
    _WATCHERS[key] = th
    th.start()
    return th


def _watch(parent_pid, fd, signum, bound_s):
    """Block until the parent exits, then signal this process (the watcher thread)."""
    if fd is not None:
        try:
            while not select.select([fd], [], [])[0]:     # readable: the parent exited
                pass
        finally:
            os.close(fd)
    while not parent_gone(parent_pid):  # also the pidfd's last look: the reparent is done
        time.sleep(POLL_S)
    signal_main(signum)
    end_later(bound_s)


def signal_main(signum):
    """
    Send ``signum`` to this process's main thread, where Python runs its handler.

    A process-directed ``kill`` from a thread can land on that thread: the handler then
    waited for the main thread's next bytecode, 7 s later in a ``time.sleep(8)`` (2 of 4
    tries, 2026-12-07); sent to the main thread it interrupts its blocking call (EINTR).
    """
    try:
        signal.pthread_kill(threading.main_thread().ident, signum)
    except (OSError, ValueError):
        os.kill(os.getpid(), signum)


def end_later(bound_s):
    """
    End this process ``bound_s`` s from now unless it ended itself: a line, stacks, exit 1.

    The parent is gone and the stop was asked for; a process still here then waits in a
    call that does not return (node processes whose pytest died of SIGSEGV were found
    still running hours later). The exit needs no GIL (:func:`exit_later`).
    """
    late = float(bound_s)
    _BACKSTOPS.extend(stacks_then_exit(
        'lifeline: the parent process ended %g s ago and this process has not stopped; '
        'exiting 1, the stacks follow (the last C error' % late,
        late, late, late + BACKSTOP_S, 1))


def stacks_then_exit(line, say_s, dump_s, exit_s, code):
    """
    Arm a GIL-free exit; return its timers (keep them referenced).

    ``line`` at ``say_s``, every thread's stack at ``dump_s``, ``_exit(code)`` at
    ``exit_s`` (s from now). Without POSIX timers ``faulthandler``'s dump exits 1 instead;
    without a usable stderr the exit is armed all the same.
    """
    timers = []
    try:
        timers = [say_later(say_s, line), exit_later(exit_s, code)]
        faulthandler.dump_traceback_later(dump_s, exit=False)
    except OSError:                     # no POSIX timers: faulthandler's exit 1
        try:
            faulthandler.dump_traceback_later(dump_s, exit=True)
        except (OSError, ValueError, RuntimeError):
            pass
    except (ValueError, RuntimeError):  # no usable stderr
        pass
    return timers


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
    prints one line naming the stall and exits with the process's code (:meth:`StopFlag.exit_code`
    of ``stop``), without the interpreter's exit. A teardown that waits while it holds
    the GIL (rclpy's ``destroy_node`` does) stops that thread too; for that case threads
    that need no GIL act :data:`BACKSTOP_S` later: a line, ``faulthandler``'s dump of
    every thread's stack, then ``_exit`` with the same code
    (:func:`exit_later`; where POSIX timers are missing, ``faulthandler``'s
    exit 1). Cancel the guard (:meth:`TeardownGuard.cancel`) when the teardown ended.
    """
    return TeardownGuard(limit_s, stop)


#: s: after the teardown guard's bound, the GIL-free backstop's (:func:`teardown_guard`)
BACKSTOP_S = 0.3


class TeardownGuard:
    """The exits of :func:`teardown_guard`: its timer thread and the GIL-free backstop."""

    def __init__(self, limit_s, stop=None):
        """Start both; ``limit_s`` in s."""
        self.limit_s = float(limit_s)
        self.stop = stop
        self.timer = threading.Timer(self.limit_s, self._abandon)
        self.timer.daemon = True
        self.timer.start()
        late = self.limit_s + BACKSTOP_S
        code = self.stop.exit_code(0) if self.stop is not None else 0
        self.backstop = stacks_then_exit(
            'teardown: the middleware did not end within %g s and holds the GIL; exiting %d '
            'without it, the stacks follow (the last C error' % (late, code),
            late - 0.02, late, late + 0.05, code)

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
        for timer in self.backstop:
            timer.cancel()
        faulthandler.cancel_dump_traceback_later()


# The GIL-free backstop: a POSIX timer (``timer_create`` with ``SIGEV_THREAD``, bound by
# ``ctypes``) makes glibc call a libc function on a thread of its own when the delay
# elapses; no Python runs on that path, so it acts while the main thread waits in C
# holding the GIL. ``faulthandler``'s own watchdog also needs no GIL but always exits 1.

#: ``<signal.h>``: the timer calls a function on a new thread
SIGEV_THREAD = 2
#: ``<time.h>``
CLOCK_MONOTONIC = 1


class _Sigevent(ctypes.Structure):
    """glibc's ``struct sigevent`` (64 bytes), its ``_sigev_thread`` member in place."""

    _fields_ = [('value', ctypes.c_void_p), ('signo', ctypes.c_int),
                ('notify', ctypes.c_int), ('function', ctypes.c_void_p),
                ('attribute', ctypes.c_void_p), ('pad', ctypes.c_byte * 32)]


class _Timespec(ctypes.Structure):
    _fields_ = [('sec', ctypes.c_long), ('nsec', ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [('interval', _Timespec), ('value', _Timespec)]


_LIBC = None


def _libc():
    global _LIBC
    if _LIBC is None:
        # the process's own symbols, libc's among them, as nodes/ros/scheduling.py loads
        # them (find_library would run ldconfig in a subprocess at every node's stop)
        lib = ctypes.CDLL(None, use_errno=True)
        lib.timer_create.argtypes = [ctypes.c_int, ctypes.POINTER(_Sigevent),
                                     ctypes.POINTER(ctypes.c_void_p)]
        lib.timer_settime.argtypes = [ctypes.c_void_p, ctypes.c_int,
                                      ctypes.POINTER(_Itimerspec), ctypes.c_void_p]
        lib.timer_delete.argtypes = [ctypes.c_void_p]
        _LIBC = lib
    return _LIBC


class CTimer:
    """A libc function of one argument called on its own thread ``delay_s`` s from now."""

    def __init__(self, delay_s, function, value):
        """
        Arm the timer.

        :param delay_s: s from now.
        :param function: the name of a libc function of one int or pointer argument.
        :param value: its argument (an int, or a ctypes buffer kept referenced here).
        :raises OSError: no POSIX timers here (the caller keeps another backstop).
        """
        lib = _libc()
        self._value = value
        arg = value if isinstance(value, int) else ctypes.addressof(value)
        self._event = _Sigevent(value=arg, notify=SIGEV_THREAD,
                                function=ctypes.cast(getattr(lib, function),
                                                     ctypes.c_void_p).value)
        self._timer = ctypes.c_void_p()
        if lib.timer_create(CLOCK_MONOTONIC, ctypes.byref(self._event),
                            ctypes.byref(self._timer)):
            raise OSError(ctypes.get_errno(), 'timer_create failed')
        sec = max(float(delay_s), 1e-3)
        spec = _Itimerspec(value=_Timespec(int(sec), int((sec % 1.0) * 1e9)))
        if lib.timer_settime(self._timer, 0, ctypes.byref(spec), None):
            err = ctypes.get_errno()
            lib.timer_delete(self._timer)
            raise OSError(err, 'timer_settime failed')
        self._armed = True

    def cancel(self):
        """Disarm (idempotent)."""
        if self._armed:
            self._armed = False
            _libc().timer_delete(self._timer)


def exit_later(delay_s, code):
    """Return a :class:`CTimer` that calls ``_exit(code)`` (``code`` 0-255) in ``delay_s`` s."""
    return CTimer(delay_s, '_exit', int(code) & 0xFF)


def say_later(delay_s, line):
    """
    Return a :class:`CTimer` that writes ``line`` to stderr in ``delay_s`` s.

    ``perror`` writes it unbuffered, followed by ``: `` and the thread's errno text.
    """
    return CTimer(delay_s, 'perror', ctypes.create_string_buffer(line.encode()))
