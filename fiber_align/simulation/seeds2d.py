# SPDX-License-Identifier: Apache-2.0
"""
The seeds, the target and the period of a two-axis run, for the offline rig and the ROS rig.

Small on purpose: the graph descriptions (``graph/rig.py``) and ``bringup`` read them
without importing the offline benches (and SciPy with them).
"""

import numpy as np

from fiber_align.alignment import sequencer2d as s2d
from fiber_align.config import load_params

#: Where the simulated graph's control rate is set (``rate_hz``, Hz).
RATE_FILE, RATE_NODE = 'plant.yaml', 'simulated_actuator'


def graph_period_s():
    """Return the simulated graph's control period (s): 1 / ``rate_hz`` of its plant."""
    return 1.0 / float(load_params(RATE_FILE, RATE_NODE)['rate_hz'])


def run_seeds(seed):
    """
    Return the noise seeds of run ``seed``: ``plant_x``, ``plant_y``, ``detector``.

    One description for the offline rig and the ROS rig (``graph/rig.py``).
    """
    return dict(plant_x=2 * int(seed), plant_y=2 * int(seed) + 1, detector=int(seed) + 1000)


def random_target(seed, seq=None):
    """Return a target ``(x, y)`` (m) drawn uniformly in the reachable square."""
    seq = seq or s2d.Sequencer2D(period_s=graph_period_s())
    rng = np.random.default_rng([seed, 14])
    return tuple(float(v) for v in rng.uniform(seq.lo, seq.hi))
