# SPDX-License-Identifier: Apache-2.0
"""
The test set-up's own checks (``test/conftest.py``), run on small test files by pytester.

A test that starts a process or rclpy without the ``ros`` marker fails at the call,
before anything starts (so ``make test-fast``, ``-m "not ros"``, never starts DDS or a
child); a test that leaves the environment or the working directory changed fails.
"""

import pytest

#: Tests of one inner file: each starts something (or leaves state) and is not marked.
UNMARKED = '''
import asyncio
import os
import subprocess

import pytest


def test_run():
    subprocess.run(['true'])


def test_popen():
    subprocess.Popen(['true'])


def test_check_output():
    subprocess.check_output(['true'])


def test_os_system():
    os.system('true')


def test_asyncio_subprocess():
    async def start():
        await asyncio.create_subprocess_exec('true')
    asyncio.run(start())


def test_rclpy_context():
    import rclpy
    rclpy.Context()


def test_rclpy_init():
    import rclpy
    rclpy.init()


@pytest.fixture
def child():
    return subprocess.Popen(['true'])


def test_fixture_starts_it(child):
    pass


def test_leaves_an_environment_variable():
    os.environ['FIBER_ALIGN_TEST_LEAK'] = '1'


def test_leaves_the_cwd(tmp_path):
    os.chdir(tmp_path)


def test_pure():
    assert sum([1, 2]) == 3


@pytest.mark.ros
def test_marked_pure():
    assert True
'''


def run_inner(pytester, source):
    """Run ``source`` as a test file in this process under ``conftest``'s hooks."""
    pytester.makepyfile(test_inner=source)
    return pytester.runpytest_inprocess('-p', 'conftest', '-o', 'markers=ros: ros', '-q',
                                        '-p', 'no:cacheprovider')


def test_an_unmarked_test_that_starts_a_process_or_rclpy_fails_before_it_starts(pytester):
    result = run_inner(pytester, UNMARKED)
    outcomes = {r.nodeid.split('::')[-1]: r.outcome
                for r in result.reprec.getreports('pytest_runtest_logreport')
                if r.when == 'call' or r.outcome != 'passed'}
    for name in ('test_run', 'test_popen', 'test_check_output', 'test_os_system',
                 'test_asyncio_subprocess', 'test_rclpy_context', 'test_rclpy_init',
                 'test_fixture_starts_it'):
        assert outcomes[name] == 'failed', (name, outcomes)
    assert outcomes['test_pure'] == 'passed'
    assert outcomes['test_marked_pure'] == 'passed'
    result.stdout.fnmatch_lines(['*test_run starts a process (subprocess) but is not marked*',
                                 '*test_rclpy_context creates an rclpy Context*'])


def test_a_test_that_leaves_global_state_fails_and_the_state_is_restored(pytester):
    import os
    result = run_inner(pytester, UNMARKED)
    result.stdout.fnmatch_lines(['*test_leaves_an_environment_variable left global state '
                                 "behind: environment ?'FIBER_ALIGN_TEST_LEAK'?*",
                                 '*test_leaves_the_cwd left global state behind*'])
    assert 'FIBER_ALIGN_TEST_LEAK' not in os.environ


@pytest.mark.parametrize('what', ['subprocess.Popen.__init__', 'os.system'])
def test_the_guard_is_removed_after_the_inner_session_only(pytester, what):
    import os            # noqa: F401 (named in ``what``)
    import subprocess    # noqa: F401 (named in ``what``)
    run_inner(pytester, 'def test_pure():\n    pass\n')
    assert hasattr(eval(what), '__wrapped__'), 'the outer session lost its guard'
