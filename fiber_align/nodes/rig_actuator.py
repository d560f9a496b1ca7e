# SPDX-License-Identifier: Apache-2.0
"""
``rig_actuator`` (node ``simulated_actuator``): one axis's plant in the two-axis rig.

The 1-D graph's :class:`~fiber_align.nodes.simulated_actuator.SimulatedActuatorNode`,
unchanged, plus what the rig needs from each axis (``graph/rig.py`` runs this executable
in ``/rig/x`` and ``/rig/y``):

- pub ``tip_position`` (sensor_msgs/JointState, joint ``bimorph_tip``: ``position[0]`` the
  model's true tip position in m, ``velocity[0]`` in m/s, the stamp of ``displacement``),
  right after each ``displacement``, every ``tip_position_every`` samples (0: off): the
  rig's optics node (``rig_optics``) computes the 2-D coupling from both axes' positions,
  which one plant's own optics model cannot;
- ``publish_clock`` (bool, read-only): lockstep ``/clock`` on (the x plant) or off (the y
  plant: the two plants advance in step, one clock is enough).

The rig sets ``optical_power_every`` 0 (the power comes from the optics node). Defaults
of the two parameters: ``config/fiber_align.yaml`` (``simulated_actuator``).
"""

import sys

from sensor_msgs.msg import JointState

from fiber_align.graph.registry import NODES
from fiber_align.nodes.ros.bus import Pub
from fiber_align.nodes.ros.params import declare, node_defaults
from fiber_align.nodes.ros.qos import sample_pub_qos
from fiber_align.nodes.ros.runtime import run_node
from fiber_align.nodes.simulated_actuator import JOINT_NAME, SimulatedActuatorNode

#: the registry's entry of this node: its name and params files
SPEC = NODES['rig_actuator']


class RigActuatorNode(SimulatedActuatorNode):
    """The simulated actuator with its true tip position published (see the module)."""

    def __init__(self, bus=None, **kwargs):
        """Build the 1-D plant node, then the rig's parameters and publisher."""
        super().__init__(bus=bus, **kwargs)
        d = node_defaults(SPEC.node, SPEC.configs)
        self.tip_every = declare(self, d, 'tip_position_every', 'publish tip_position '
                                 '(true tip position, m) every N samples; 0: off', 0,
                                 1000000, True)
        if not declare(self, d, 'publish_clock', 'lockstep: publish /clock (the rig: '
                       'the x plant only)', read_only=True) and self.pub_clock is not None:
            self.destroy_publisher(self.pub_clock)
            self.pub_clock = None
        self.pub_tip = Pub(self, JointState, 'tip_position',
                           sample_pub_qos(self.sync_mode == 'lockstep'), bus)
        self._tip = JointState(name=[JOINT_NAME], position=[0.0], velocity=[0.0])
        self.n_tip = 0

    def _publish_sample(self, t_s):
        """Publish sample ``self.k`` as the 1-D plant does, then its true tip position."""
        super()._publish_sample(t_s)
        if self.tip_every and self.k % self.tip_every == 0:
            tip = self._tip
            tip.header.stamp = self._js.header.stamp
            tip.position[0] = float(self.plant.position_m)
            tip.velocity[0] = float(self.plant.velocity_m_per_s)
            self.pub_tip.publish(tip)
            self.n_tip += 1

    def sent_counts(self):
        """Return published message counts per topic."""
        return dict(super().sent_counts(), tip_position=self.n_tip)


def main(args=None):
    """Run the node (demo_nodes_py idiom; bad parameters: one line, exit 2)."""
    return run_node(RigActuatorNode, SPEC.node, args)


if __name__ == '__main__':
    sys.exit(main())
