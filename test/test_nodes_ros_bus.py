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
        assert timer.callbacks == [plant.clock._on_tick, driver._on_tick]    # the plant first
        assert timer.watchdogs == {driver._on_tick}
        assert driver.trigger_cleanup() == Ret.SUCCESS
        assert timer.callbacks == [plant.clock._on_tick]
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()


class _Node:
    """Stands in for the node a SampleTimer makes its rclpy timer on."""

    def create_timer(self, period_s, callback, clock=None):
        return None


def test_a_watchdog_pauses_while_every_plant_of_the_process_is_held():
    from fiber_align.nodes.ros.bus import SampleTimer
    timer = SampleTimer(_Node(), 1e-3, None)
    calls, plants = [], {'x': True, 'y': True}

    def plant(name):
        def tick():
            calls.append(name)
            return plants[name]
        return tick

    def watchdog():
        calls.append('watchdog')
    timer.callbacks += [plant('x'), plant('y'), watchdog]
    timer.watchdogs.add(watchdog)
    timer._tick()
    assert calls == ['x', 'y', 'watchdog']
    plants['x'] = False                         # one plant held, the other runs
    calls.clear()
    timer._tick()
    assert calls == ['x', 'y', 'watchdog']
    plants['y'] = False                         # every plant held: the world stopped
    calls.clear()
    timer._tick()
    assert calls == ['x', 'y']
    timer.remove(watchdog)
    assert watchdog not in timer.watchdogs and timer.callbacks[-1] is not watchdog
    alone = SampleTimer(_Node(), 1e-3, None)    # a process without a plant (hardware)
    alone.callbacks.append(watchdog)
    alone.watchdogs.add(watchdog)
    calls.clear()
    alone._tick()
    assert calls == ['watchdog']
