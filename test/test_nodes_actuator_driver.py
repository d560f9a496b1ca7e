# SPDX-License-Identifier: Apache-2.0
"""
``actuator_driver`` in this process, without a graph: its activation.

The lockstep driver keeps the pairs that come before it is active.

Under ``ros2 launch`` the plant starts its sample clock once a ``drive_voltage``
publisher exists, which the driver creates at configure, not at activate. The first
sample's feedforward and feedback could then reach a configured, inactive driver, which
dropped them, and the lockstep plant waited for that drive forever (a clean-clone run of
``test_ros2_cli.py::test_lockstep_launch_equals_simulate_sample_for_sample``, 2026-11-30).

A realtime driver activated again does not count its inactive time as a loss of input
(its watchdog tripped at once when its timer ran before the first new command: a
clean-clone run of ``test_nodes_actuator_driver_mdt693b.py`` with two CPU hogs, 2026-11-30).
"""

import time

import pytest

from fiber_align.nodes.actuator_driver import ActuatorDriverNode
from test_nodes_ros_params import make

pytestmark = pytest.mark.ros


def test_pairs_before_activate_are_driven_at_activate_in_order(ctx):
    """ff/fb of samples 0 and 1 arrive while inactive: two drives at activate, in order."""
    drv = make(ctx, ActuatorDriverNode, 'sync_mode:=lockstep')
    drv.trigger_configure()
    sent = []
    drive = drv._drive
    drv._drive = lambda drives: (sent.extend(v for _, v in drives), drive(drives))
    for ff, fb in ((10.0, 1.0), (12.0, -0.5)):
        drv._on_input('', True, ff)
        drv._on_input('', False, fb)
    assert sent == []                   # inactive: nothing driven, nothing dropped
    drv.trigger_activate()
    assert sent == [11.0, 11.5]
    drv._on_input('', True, 13.0)
    drv._on_input('', False, 0.25)
    assert sent == [11.0, 11.5, 13.25]  # active: each pair at once


def test_a_reactivated_driver_does_not_trip_on_its_inactive_time(ctx):
    """Deactivate, wait beyond the watchdog timeout, activate: the first tick is no trip."""
    drv = make(ctx, ActuatorDriverNode)
    assert drv.get_parameter('sync_mode').value == 'realtime'
    drv.trigger_configure()
    drv.trigger_activate()
    core = drv.s.driver.cores['']
    drv._on_input('', True, 10.0)
    drv._on_input('', False, 0.5)
    assert core.v == 10.5
    drv.trigger_deactivate()
    time.sleep(2 * core.timeout)
    drv.trigger_activate()
    drv._on_tick()                          # the timer before the first new command
    assert core.watchdog_count == 0 and not core.tripped
    drv._on_input('', True, 11.0)
    drv._on_input('', False, 0.5)
    assert core.v == 11.5                   # driven at once, no recovery hold


def test_a_driver_destroyed_while_configured_stops_its_publisher_watch(ctx):
    """
    The watch's thread counts publishers through the rcl node's raw pointer (ctypes).

    A driver destroyed without a cleanup transition (a process's exit, a test's) left it
    running on a freed node: a full suite's pytest process died of a segmentation fault
    some modules later (clean clone I, 2026-12-07, exit 139 without a traceback).
    """
    import threading
    drv = make(ctx, ActuatorDriverNode)
    drv.trigger_configure()
    drv.trigger_activate()
    thread = drv.watch._thread
    assert thread.is_alive()
    ctx[1].remove(drv)                      # destroyed here, not by the fixture
    drv.destroy_node()
    assert not thread.is_alive() and drv.watch is None
    assert thread not in threading.enumerate()
