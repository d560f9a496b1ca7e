# SPDX-License-Identifier: Apache-2.0
"""
A scenario's values at sample times, clamped to the graph's setpoint range (pure).

What the ``scenario_runner`` node publishes for each sample and what ``bringup``'s trace
compares against: :class:`Source` (the references of
:mod:`fiber_align.simulation.scenarios`) and :func:`setpoint_range`. SI units (m, V, s).
"""

from fiber_align.simulation import scenarios


class Source:
    """
    A scenario's values at sample times.

    :param name: a name in :data:`fiber_align.simulation.scenarios.NAMES`.
    :param lo: lowest setpoint (m).
    :param hi: highest setpoint (m).
    """

    def __init__(self, name, lo=0.0, hi=float('inf')):
        """Build the scenario of :mod:`fiber_align.simulation.scenarios`."""
        self.sc = scenarios.make(name)
        self.lo, self.hi = max(0.0, float(lo)), float(hi)

    @property
    def open_loop(self):
        """Return True for an open-loop drive (V) instead of a setpoint (m)."""
        return self.sc.open_loop

    def value(self, t):
        """Return the setpoint (m) or, open loop, the drive (V) at sample time ``t`` (s)."""
        if self.sc.open_loop:
            return self.sc.drive(t)
        return min(max(self.sc.reference(t), self.lo), self.hi)


def setpoint_range(lo, hi, reach_m):
    """Return the clamp range (m) of the setpoints: ``[max(0, lo), min(hi, reach)]``."""
    return max(0.0, float(lo)), (min(float(hi), float(reach_m)) if reach_m > 0
                                 else float(hi))
