# SPDX-License-Identifier: Apache-2.0
"""A node's status without ROS: the latch, the standing conditions, the tasks."""

from fiber_align.control.health import ERROR, OK, Status, WARN


def test_an_event_is_latched_and_a_steady_status_as_severe_replaces_it():
    st = Status(hold_s=60.0)
    st.summary(OK, 'running')
    st.warn('late drive')
    assert st.reports('/n')[0][1:3] == (WARN, 'late drive')
    st.summary(ERROR, 'device lost')
    assert st.reports('/n')[0][1:3] == (ERROR, 'device lost')
    st.summary(OK, 'running')
    st.error('refused')
    st.resolve()
    assert st.reports('/n')[0][1:3] == (OK, 'running')


def test_a_condition_stands_until_cleared_and_a_failing_task_is_its_error():
    st = Status()
    st.summary(OK, 'ready')
    st.condition('cycles', 'missed 2 % of the periods')
    st.add('sensor', lambda stat: 1 / 0)
    own, task = st.reports('/n')
    assert own[1:3] == (WARN, 'ready; missed 2 % of the periods')
    assert task[0] == '/n: sensor' and task[1] == ERROR and 'ZeroDivisionError' in task[2]
    st.condition('cycles', None)
    assert st.reports('/n')[0][1:3] == (OK, 'ready')
