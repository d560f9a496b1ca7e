# SPDX-License-Identifier: Apache-2.0
"""
The emulator started as a child process, and the bounded stop of a child.

The emulator (``fiber-align emulate``) ends with the process that started it by itself
(:func:`fiber_align.lifeline.watch_parent`), as every executable of the package does: a
parent killed with SIGKILL leaves no emulator behind keeping its pty and socket.
"""

import json
import os
import select
import signal
import subprocess
import sys

from fiber_align.hardware import errors as er

#: s (wall): the longest wait for the emulator's JSON line.
EMULATE_TIMEOUT_S = 20.0


def emulator_options(seed, target_m=None, slot_m=None, meter_floor_w=None):
    """
    Return the options of ``fiber-align emulate`` for a run (``bringup --hardware --emulate``).

    :param seed: the emulators' seed; :param target_m: the rig's output core ``(x, y)``
        (m; ``None``: the 1-D bench), or the array's chip ``(x0, y0, roll0)`` (m, m, rad:
        ``--array``); :param slot_m: the 1-D slot position (m);
        :param meter_floor_w: the PM100's reading floor (W); ``None``: the emulator's.
    """
    extra = ['--seed', str(seed)]
    if target_m is not None and len(target_m) == 3:
        extra += ['--array', '--target-x', repr(target_m[0]), '--target-y',
                  repr(target_m[1]), '--roll', repr(target_m[2])]
    elif target_m is not None:
        extra += ['--rig', '--target-x', repr(target_m[0]), '--target-y', repr(target_m[1])]
    if slot_m is not None:
        extra += ['--slot', repr(float(slot_m))]
    if meter_floor_w is not None:
        extra += ['--meter-floor', repr(float(meter_floor_w))]
    return extra


def start_emulator(extra=(), quiet=True, priority=0):
    """
    Start ``fiber-align emulate`` as a child of this process; return ``(proc, info)``.

    :param extra: its options (``--slot``, ``--seed``, ...).
    :param priority: run it under ``SCHED_FIFO`` at this priority (1..99; 0: the normal
        policy; refused without the right to: then the normal policy).
    :returns: the Popen and the JSON line it printed (``serial_link``, ``visa_resource``).
    :raises DeviceError: no JSON line within :data:`EMULATE_TIMEOUT_S`.
    """
    def preexec():
        try:        # before exec: every thread of the emulator inherits it
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (AttributeError, OSError):
            pass
    proc = subprocess.Popen([sys.executable, '-m', 'fiber_align.cli', 'emulate'] + list(extra),
                            stdout=subprocess.PIPE, stderr=None if not quiet else
                            subprocess.DEVNULL, text=True, start_new_session=True,
                            preexec_fn=preexec if priority > 0 else None)
    ready, _, _ = select.select([proc.stdout], [], [], EMULATE_TIMEOUT_S)
    line = proc.stdout.readline() if ready else ''
    try:
        return proc, json.loads(line)
    except ValueError:
        code = stop_process(proc) if proc.poll() is None else proc.returncode
        why = ('no JSON line within %g s' % EMULATE_TIMEOUT_S if not ready else
               'it ended with exit code %s before its JSON line' % code if not line else
               'its first line is not JSON')
        raise er.DeviceError('fiber-align emulate', er.NO_REPLY,
                             '%s (%r)' % (why, line.strip())) from None


def emulator_truth(proc, timeout_s=2.0):
    """
    Return the truth of a running ``fiber-align emulate`` (its SIGUSR1 line), or ``None``.

    :param proc: the Popen of :func:`start_emulator`; waits at most ``timeout_s`` (s).
    """
    if proc.poll() is not None:
        return None
    proc.send_signal(signal.SIGUSR1)
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    try:
        return json.loads(proc.stdout.readline()).get('truth') if ready else None
    except ValueError:
        return None


def stop_process(proc, grace_s=5.0):
    """SIGINT ``proc`` (a Popen), SIGKILL after ``grace_s`` s; return its exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5.0)
    return proc.returncode
