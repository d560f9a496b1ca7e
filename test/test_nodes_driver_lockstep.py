# SPDX-License-Identifier: Apache-2.0
"""
The lockstep driver keeps the pairs that come before it is active.

Under ``ros2 launch`` the plant starts its sample clock once a ``drive_voltage``
publisher exists, which the driver creates at configure, not at activate. The first
sample's feedforward and feedback could then reach a configured, inactive driver, which
dropped them, and the lockstep plant waited for that drive forever (a clean-clone run of
``test_ros2_cli.py::test_lockstep_launch_equals_simulate_sample_for_sample``, 2026-11-30).
"""

from std_msgs.msg import Float64

from fiber_align.nodes.actuator_driver import ActuatorDriverNode
from test_nodes_parameters import ctx, make  # noqa: F401 (ctx: a fixture)


def test_pairs_before_activate_are_driven_at_activate_in_order(ctx):  # noqa: F811
    """ff/fb of samples 0 and 1 arrive while inactive: two drives at activate, in order."""
    drv = make(ctx, ActuatorDriverNode, 'sync_mode:=lockstep')
    drv.trigger_configure()
    sent = []
    publish = drv._publish
    drv._publish = lambda v: (sent.append(v), publish(v))
    for ff, fb in ((10.0, 1.0), (12.0, -0.5)):
        drv._on_ff(Float64(data=ff))
        drv._on_fb(Float64(data=fb))
    assert sent == []                   # inactive: nothing driven, nothing dropped
    drv.trigger_activate()
    assert sent == [11.0, 11.5]
    drv._on_ff(Float64(data=13.0))
    drv._on_fb(Float64(data=0.25))
    assert sent == [11.0, 11.5, 13.25]  # active: each pair at once
