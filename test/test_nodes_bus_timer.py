# SPDX-License-Identifier: Apache-2.0
"""One timer per process: the plants' sample clocks and the drivers' watchdogs share it."""

import pytest

pytestmark = pytest.mark.ros


def test_a_composed_drivers_watchdog_ticks_on_the_plants_timer_after_the_plant():
    import rclpy
    from rclpy.lifecycle import TransitionCallbackReturn as Ret

    from fiber_align.nodes import control_graph
    from fiber_align.nodes.ros.bus import SampleTimer
    rclpy.init()
    nodes = []
    try:
        nodes, bus = control_graph.build(['simulated_actuator', 'actuator_driver'])
        plant, driver = nodes
        assert driver.get_parameter('sync_mode').value == 'realtime'
        assert driver.trigger_configure() == Ret.SUCCESS
        (timer,) = bus.timers.values()          # one timer for the process's period
        assert isinstance(timer, SampleTimer) and driver._timer is timer
        assert timer.callbacks == [plant._on_tick, driver._on_tick]    # the plant first
        assert driver.trigger_cleanup() == Ret.SUCCESS
        assert timer.callbacks == [plant._on_tick]
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
