# SPDX-License-Identifier: Apache-2.0
"""Bounded subprocess runs for the integration tests (a hanging test is a failing test)."""

import contextlib
import ctypes
import os
import subprocess
import sys
import time

import pytest

from fiber_align.hardware.process import stop_process


def alive(pid):
    """Return whether process ``pid`` runs (a zombie of a dead parent counts as gone)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:
        with open('/proc/%d/stat' % pid, encoding='ascii') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def wait_log(log, text, seconds, proc):
    """Wait (bounded, s) until ``text`` is in the file ``log`` or ``proc`` exited."""
    end = time.monotonic() + seconds
    while time.monotonic() < end and proc.poll() is None:
        if text in log.read_text(errors='replace'):
            return True
        time.sleep(0.1)
    return text in log.read_text(errors='replace')


def joint_state(*position):
    """Return a sensor_msgs/JointState of ``bimorph_tip`` at ``position`` (m)."""
    from sensor_msgs.msg import JointState
    return JointState(name=['bimorph_tip'], position=list(position))


def stop(proc, grace_s=10.0):
    """SIGINT ``proc`` if it still runs, then SIGKILL after ``grace_s`` (s)."""
    stop_process(proc, grace_s)


def run_bounded(cmd, timeout, grace_s=10.0):
    """
    Run ``cmd`` with a timeout (s); return ``(returncode, combined output)``.

    On a timeout the process gets SIGINT first (``bringup`` and the demo stop their
    nodes cleanly), then SIGKILL after ``grace_s``, so no child outlives the test.
    """
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    out = ''
    try:
        out, _ = proc.communicate(timeout=timeout)
    finally:
        stop(proc, grace_s)
    return proc.returncode, out


def run_bringup(tmp_path, *options, timeout=60):
    """
    Run ``bringup OPTIONS --quiet --summary`` (bounded, s); return ``(code, output, summary)``.

    ``summary`` is the JSON summary as a dict (empty when bringup wrote none).
    """
    import json
    path = tmp_path / 'summary.json'
    code, out = run_bounded([sys.executable, '-m', 'fiber_align.bringup', *options,
                             '--quiet', '--summary', str(path)], timeout)
    return code, out, json.loads(path.read_text()) if path.exists() else {}


def spin_until(executor, cond, bound_s, slice_s=0.01):
    """
    Spin ``executor`` until ``cond()`` holds or ``bound_s`` (s) pass; return ``cond()``.

    ``cond`` is checked once a ``slice_s`` (s), the callbacks that came in between all
    taken first: a check after each callback, when it scans what a 1 kHz stream has
    gathered, makes the client fall behind its streams and read a growing backlog.
    """
    end = time.monotonic() + bound_s
    while True:
        now = time.monotonic()
        if now >= end:
            return bool(cond())
        stop_at = min(end, now + slice_s)
        while time.monotonic() < stop_at:
            executor.spin_once(timeout_sec=max(0.0, min(0.002, stop_at - time.monotonic())))
        if cond():
            return True


def change_state_client(ctx, name, bound_s=20.0):
    """
    Return ``(node, executor, client)``: a client of ``name``'s ``change_state``.

    The client is ready (asserted within ``bound_s`` s) on a test node on ``ctx``.
    ``ctx`` is the ``(context, nodes)`` fixture: the node goes into ``nodes``, which the
    fixture destroys, also on failure.
    """
    import rclpy
    from lifecycle_msgs.srv import ChangeState
    context, nodes = ctx
    node = rclpy.create_node('test_change_state', context=context)
    nodes.append(node)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = node.create_client(ChangeState, name + '/change_state')
    assert spin_until(executor, client.service_is_ready, bound_s), name + ': no change_state'
    return node, executor, client


def level(status):
    """Return the severity (int) of a diagnostic_msgs/DiagnosticStatus."""
    return status.level[0] if isinstance(status.level, bytes) else int(status.level)


@contextlib.contextmanager
def nodes_on_executor(*factories):
    """
    Yield ``(executor, nodes)``: rclpy started, each factory's node on one executor.

    Everything is torn down after the block (the nodes destroyed, rclpy shut down), also
    when a factory or the block raises.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    rclpy.init()
    ex = SingleThreadedExecutor()
    nodes = []
    try:
        for make in factories:
            nodes.append(make())
            ex.add_node(nodes[-1])
        yield ex, nodes
    finally:
        for n in nodes:
            ex.remove_node(n)
            n.destroy_node()
        ex.shutdown()
        rclpy.try_shutdown()


#: umount2(2) flag: detach now, even if something still holds the filesystem
MNT_DETACH = 2


@contextlib.contextmanager
def tmpfs(path, size_bytes):
    """Mount a tmpfs of ``size_bytes`` at ``path`` (mount(2), root), unmount it after."""
    path.mkdir()
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mount(b'tmpfs', str(path).encode(), b'tmpfs', 0,
                  b'size=%d' % size_bytes) != 0:
        pytest.fail('a %g MB tmpfs needs root (mount(2)): %s'
                    % (size_bytes / 2**20, os.strerror(ctypes.get_errno())))
    try:
        yield path
    finally:
        libc.umount2(str(path).encode(), MNT_DETACH)
