# SPDX-License-Identifier: Apache-2.0
"""
The seeds and the target of a two-axis run, for the offline rig and the ROS rig alike.

Small on purpose: the graph descriptions (``graph/rig.py``) and ``bringup`` read them
without importing the offline benches (and SciPy with them).
"""

import numpy as np

from fiber_align.alignment import sequencer2d as s2d


def run_seeds(seed):
    """
    Return the noise seeds of run ``seed``: ``plant_x``, ``plant_y``, ``detector``.

    One description for the offline rig and the ROS rig (``graph/rig.py``).
    """
    return dict(plant_x=2 * int(seed), plant_y=2 * int(seed) + 1, detector=int(seed) + 1000)


def random_target(seed, seq=None):
    """Return a target ``(x, y)`` (m) drawn uniformly in the reachable square."""
    seq = seq or s2d.Sequencer2D()
    rng = np.random.default_rng([seed, 14])
    return tuple(float(v) for v in rng.uniform(seq.lo, seq.hi))
