# SPDX-License-Identifier: Apache-2.0
"""``lifeline.StopFlag``: set by stop signals; a second one during the stop is the exit code."""

import signal

from fiber_align.lifeline import StopFlag


def test_one_signal_stops_with_the_ordinary_code():
    f = StopFlag()
    assert not f.is_set()
    f.note(signal.SIGINT)
    assert f.is_set() and f.exit_code(0) == 0 and f.exit_code(2) == 2


def test_a_second_signal_during_the_stop_is_reported_the_shell_way():
    f = StopFlag()
    f.note(signal.SIGINT)
    f.note(signal.SIGTERM)
    assert f.exit_code(0) == 128 + signal.SIGTERM


def test_set_and_clear_do_not_count_as_a_signal():
    f = StopFlag()
    f.set()
    f.set()
    assert f.is_set() and f.exit_code(0) == 0
    f.clear()
    assert not f.is_set()
