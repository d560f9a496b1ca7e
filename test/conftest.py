# SPDX-License-Identifier: Apache-2.0
"""Shared test set-up: own ROS 2 domain, one colcon build, the `ros` marker checked."""

import itertools
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile

from pg_cluster import find_bindir, PgServer
import pytest

# Discovery stays on this machine; no multicast leaves it.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
# Each pytest process gets a domain from its pid, so parallel runs (and helpers' runs)
# never see each other's nodes, and each test module the next one (`_module_domain`).
# Domains 1-100 are safe with Fast DDS port mapping.
KEEP_DOMAIN = 'FIBER_ALIGN_TEST_KEEP_DOMAIN' in os.environ
if not KEEP_DOMAIN:
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)
# Every graph writes the run catalogue by default ($ROS_HOME/fiber_align/catalog.db,
# docs/records.md): the tests' graphs (and their ROS logs) write into a folder of the test
# session's, never into the user's ~/.ros.
os.environ['ROS_HOME'] = tempfile.mkdtemp(prefix='fiber_align_test_ros_home_')


ROOT = Path(__file__).resolve().parents[1]
#: What a colcon source copy of the package leaves out (build products, venvs, runs).
COPY_IGNORE = shutil.ignore_patterns('.venv', '.git', 'build', 'install', 'log', '__pycache__',
                                     '.pycache', '*.egg-info', 'runs', 'out', '.pytest_cache')


@pytest.fixture(scope='session')
def colcon_workspace(tmp_path_factory):
    """
    Return ``(ws, proc)``: the package built once per session by ``colcon build``.

    ``ws`` is the workspace (``ws/install/fiber_align`` the install prefix), ``proc`` the
    finished ``colcon build`` (``returncode``, ``stdout``, ``stderr``). Shared by
    ``test_package_colcon.py`` and ``test_ros2_cli.py``.
    """
    colcon = Path(sys.executable).with_name('colcon')
    if not colcon.exists():
        pytest.fail('colcon is not installed in this environment (pip install colcon-core '
                    'colcon-ros, part of the test extras)')
    ws = tmp_path_factory.mktemp('colcon') / 'ws'
    shutil.copytree(ROOT, ws / 'src' / 'fiber_align', ignore=COPY_IGNORE)
    proc = subprocess.run([str(colcon), 'build', '--event-handlers', 'console_direct-'],
                          cwd=ws, capture_output=True, text=True, timeout=300)
    return ws, proc


# --- The `ros` marker, checked: a test that starts rclpy or any process carries it. ---
# `make test-fast` runs `-m "not ros"`; a test that started DDS or a child without the
# marker would run there unlocked, beside other graphs. The guard wraps the entry points
# (rclpy's Context, subprocess.Popen, os.posix_spawn and friends) once per session and fails
# the running test at the call, before anything starts, when it is not marked `ros`.

#: The test items now running (a stack: pytester runs a session inside a test).
_RUNNING = []
#: How many sessions installed the guard (the last one out restores the originals).
_GUARD = {'depth': 0, 'saved': []}


def _check(what):
    """Fail the running test if it is not marked ``ros`` (``what``: the call it made)."""
    if _GUARD.get('session_teardown'):
        return      # a session fixture's teardown runs in whichever test came last
    if _RUNNING and _RUNNING[-1].get_closest_marker('ros') is None:
        pytest.fail(f'{_RUNNING[-1].nodeid} {what} but is not marked ros: add '
                    f'`pytestmark = pytest.mark.ros` (or @pytest.mark.ros)', pytrace=False)


def _wrap(owner, name, what):
    """Replace ``owner.name`` by a checked call; remember the original."""
    original = getattr(owner, name, None)
    if original is None:
        return

    def checked(*args, **kwargs):
        _check(what)
        return original(*args, **kwargs)

    checked.__wrapped__ = original
    _GUARD['saved'].append((owner, name, original))
    setattr(owner, name, checked)


def _guard_targets():
    """Yield ``(owner, name, what)``: every call that starts ROS or a process."""
    yield subprocess.Popen, '__init__', 'starts a process (subprocess)'
    # A bare fork (multiprocessing workers, flake8's jobs) runs no other program and
    # starts no DDS participant of its own, so it is not a process start here.
    for name in ('posix_spawn', 'posix_spawnp', 'system', 'execv', 'execve', 'spawnv',
                 'spawnve'):
        yield os, name, f'starts a process (os.{name})'
    try:
        import rclpy.context
    except ImportError:         # a pure environment: nothing ROS to start
        return
    yield rclpy.context.Context, '__init__', 'creates an rclpy Context'
    yield rclpy.context.Context, 'init', 'initialises rclpy (Context.init)'


def pytest_sessionstart(session):
    """Install the guard (once, however many sessions nest)."""
    if _GUARD['depth'] == 0:
        # matplotlib's first import on a machine builds its font cache by running
        # fc-list: a set-up step, done before the guard, not a process a test starts
        try:
            import matplotlib.font_manager  # noqa: F401
        except ImportError:
            pass
        for owner, name, what in _guard_targets():
            _wrap(owner, name, what)
    _GUARD['depth'] += 1


def pytest_sessionfinish(session):
    """Restore the originals when the outermost session ends."""
    _GUARD['depth'] -= 1
    if _GUARD['depth'] == 0:
        while _GUARD['saved']:
            owner, name, original = _GUARD['saved'].pop()
            setattr(owner, name, original)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Know which test runs (its fixtures' set-up and teardown included)."""
    _RUNNING.append(item)
    try:
        yield
    finally:
        _RUNNING.pop()


_MODULES = itertools.count(1)


@pytest.fixture(autouse=True, scope='module')
def _module_domain():
    """
    Give each test module a ROS domain of its own for its tests and its module graphs.

    A graph that a module stopped is gone from the domain only once its last process
    exited and its participants' leases ran out; until then, in a shared domain, it
    still publishes into the next module's graph (a stopping driver's latched
    ``drive_held`` true, say).
    """
    if KEEP_DOMAIN:
        yield
        return
    old = os.environ['ROS_DOMAIN_ID']
    os.environ['ROS_DOMAIN_ID'] = str(1 + (os.getpid() + next(_MODULES)) % 100)
    try:
        yield
    finally:
        os.environ['ROS_DOMAIN_ID'] = old


# --- No test leaves global state behind (the environment, the working directory). ---

#: Variables not a test's to restore: pytest sets the first per test phase, threadpoolctl
#: (imported by scipy) the second once, at import.
_PYTEST_OWN = {'PYTEST_CURRENT_TEST', 'KMP_DUPLICATE_LIB_OK'}


@pytest.fixture(autouse=True)
def _no_global_state_left(request):
    """Fail a test that changed ``os.environ`` or the cwd and did not restore them."""
    env, cwd = dict(os.environ), os.getcwd()
    yield
    changed = sorted(k for k in set(env) | set(os.environ)
                     if env.get(k) != os.environ.get(k) and k not in _PYTEST_OWN)
    now = os.getcwd()
    if now != cwd:
        os.chdir(cwd)
    for key in changed:         # restore, so one offender does not fail every later test
        if key in env:
            os.environ[key] = env[key]
        else:
            os.environ.pop(key, None)
    if changed or now != cwd:
        pytest.fail(f'{request.node.nodeid} left global state behind: environment '
                    f'{changed}, cwd {now!r} (was {cwd!r}); use monkeypatch.setenv / '
                    f'monkeypatch.chdir', pytrace=False)


@pytest.fixture
def ctx():
    """
    Yield ``(context, nodes)``: a private rclpy context, its nodes destroyed after.

    A test that builds nodes in this process (in ``nodes``) on a context of its own, shut
    down after it: no global rclpy state is left. The test is marked ``ros``.
    """
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context)
    nodes = []
    yield context, nodes
    for n in nodes:
        n.destroy_node()
    rclpy.shutdown(context=context)


# --- A PostgreSQL server of the tests' own (test/pg_cluster.py), once per session. ---

@pytest.fixture(scope='session')
def pg_server():
    """
    Yield a running :class:`pg_cluster.PgServer`; stopped and removed after, also on failure.

    It starts processes: a test that uses it is marked ``ros`` (and ``postgres``).
    """
    bindir = find_bindir()
    if bindir is None:
        pytest.fail('no PostgreSQL server binaries (initdb, pg_ctl): install the server '
                    '(README: set-up), or set FIBER_ALIGN_PG_BINDIR')
    server = PgServer(bindir)
    try:
        server.start()
        yield server
    finally:
        _GUARD['session_teardown'] = True       # not the last test's own process start
        try:
            server.remove()
        finally:
            _GUARD['session_teardown'] = False


_DATABASES = itertools.count(1)


@pytest.fixture
def pg_url(pg_server):
    """Return the URL of a new, empty database on the session's PostgreSQL server."""
    return pg_server.create_database('t%d_%d' % (os.getpid(), next(_DATABASES)))
