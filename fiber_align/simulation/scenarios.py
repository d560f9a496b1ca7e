# SPDX-License-Identifier: Apache-2.0
"""
Reference generators of the control scenarios (SEED-NOTES section 7), SI units.

``make(name)`` returns a :class:`Scenario`; ``reference(t)`` gives the target
displacement (m) at time ``t`` (s). The actuator moves one way from rest (drive >= 0),
so the paper's 82 um sine and triangle are read as spanning 0..82 um (bias 41 um).

``staircase`` holds a sequence of levels (:data:`STAIRCASE_M`, ``STAIRCASE_HOLD_S``
each): steps of several sizes, up and down, each from the non-rest hysteresis state the
previous moves left (the alignment sequencer's switch and re-peak moves are such steps).

``hysteresis-experiment`` is open loop: ``drive(t)`` gives the voltage (V), a 0-72 V
triangle at 0.1 Hz (paper Section 5.1), and there is no reference.
"""

from dataclasses import dataclass
import math

#: The reference scenarios (a setpoint source for one loop), and those a loop tracks.
NAMES = ('step', 'sine', 'triangle', 'staircase', 'hysteresis-experiment')
TRACKING = NAMES[:4]
#: The alignment scenarios of every machine (:mod:`fiber_align.simulation.harness`): the
#: one-axis machine, the x-y rig, the coupled station, the fiber array.
MACHINE_SCENARIOS = {'one': ('align', 'switch', 'track'),
                     'rig': ('align2d', 'track2d', 'switch2d'),
                     'station': ('station', 'cure'),
                     'array': ('array',)}
ALIGNMENT = tuple(n for names in MACHINE_SCENARIOS.values() for n in names)
#: What the 1-D graph's ``scenario`` argument takes (``none``: no runner).
GRAPH = ('none',) + NAMES + ('align',)
STEP_M = 82e-6
SINE_HZ = 0.75
TRIANGLE_HZ = 1.0
HYST_HZ = 0.1
HYST_VMAX = 72.0
# staircase levels (m): up and down steps of 5-62 um from non-rest hysteresis states
STAIRCASE_M = (45e-6, 82e-6, 20e-6, 60e-6, 45e-6, 10e-6, 45e-6, 70e-6, 35e-6, 40e-6,
               0.0, 45e-6)
STAIRCASE_HOLD_S = 0.025


@dataclass
class Scenario:
    """
    A named reference (or open-loop drive) with its default duration and metrics window.

    :param name: scenario name.
    :param duration_s: default run length (s).
    :param skip_s: leading time (s) left out of the tracking metrics (one period).
    :param amplitude_m: peak reference (m); 0 for open loop.
    :param frequency_hz: frequency (Hz) of periodic references; 0 for a step.
    """

    name: str
    duration_s: float
    skip_s: float
    amplitude_m: float = STEP_M
    frequency_hz: float = 0.0

    @property
    def open_loop(self):
        """Tell whether the scenario drives a voltage instead of tracking a reference."""
        return self.name == 'hysteresis-experiment'

    def reference(self, t):
        """Compute the target displacement (m) at time t (s)."""
        a, f = self.amplitude_m, self.frequency_hz
        if self.name == 'step':
            return a if t >= 0.0 else 0.0
        if self.name == 'sine':
            return 0.5 * a * (1.0 - math.cos(2.0 * math.pi * f * t))
        if self.name == 'triangle':
            return a * triangle_wave(f * t)
        if self.name == 'staircase':
            i = int(t / STAIRCASE_HOLD_S + 1e-9) if t > 0.0 else 0
            return STAIRCASE_M[min(i, len(STAIRCASE_M) - 1)]
        return 0.0

    def drive(self, t):
        """Compute the open-loop voltage (V) of hysteresis-experiment at time t (s)."""
        return HYST_VMAX * triangle_wave(HYST_HZ * t)


def triangle_wave(phase):
    """Return the unit triangle (0 at phase 0, 1 at phase 0.5, 0 at phase 1), periodic."""
    p = phase - math.floor(phase)
    return 2.0 * p if p < 0.5 else 2.0 * (1.0 - p)


def make(name):
    """Return the :class:`Scenario` called ``name`` (see :data:`NAMES`)."""
    if name == 'step':
        return Scenario('step', 0.05, 0.0)
    if name == 'sine':
        return Scenario('sine', 10.0, 1.0 / SINE_HZ, STEP_M, SINE_HZ)
    if name == 'triangle':
        return Scenario('triangle', 10.0, 1.0 / TRIANGLE_HZ, STEP_M, TRIANGLE_HZ)
    if name == 'staircase':
        return Scenario('staircase', STAIRCASE_HOLD_S * len(STAIRCASE_M), 0.0,
                        max(STAIRCASE_M))
    if name == 'hysteresis-experiment':
        return Scenario('hysteresis-experiment', 1.0 / HYST_HZ, 0.0, 0.0, HYST_HZ)
    raise ValueError('unknown scenario %r (allowed: %s)' % (name, ', '.join(NAMES)))
