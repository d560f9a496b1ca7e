# SPDX-License-Identifier: Apache-2.0
"""
The 2-D first-light threshold against the detector's dark readings: no false first light.

The sequencer estimates the floor from ``floor_samples`` dark readings at rest and sets
its threshold ``threshold_sigma`` standard deviations above their mean; the dark reading
is half-normal (the detector's ``|noise|``). From 10 readings the estimate came out low
often enough that two dark readings in a row passed it in 0.3-0.7 % of the searches: a
false first light at the start of the walk, then "light lost while peaking" (one rig run
of 20 cycles in three). Offline, with the real detector and sequencer.
"""

from fiber_align.alignment.sequencer2d import Sequencer2D
from fiber_align.alignment.states import IDLE, PEAKING, SEARCHING
from fiber_align.plant.optics import Detector

T = 1e-3
#: searches run; with 10 floor readings 9 of them found false light
SEARCHES = 3000
#: spiral readings watched after the floor (the walk reaches real light later)
LOOK = 20


def false_first_lights(searches, seed=0):
    """
    Return how many of ``searches`` left SEARCHING for PEAKING on dark readings only.

    As the rig's cycles run: release, dark readings at rest in IDLE (they count for the
    floor), align, then the walk's first :data:`LOOK` readings (dark too).
    """
    det = Detector(noise_floor_w=1e-10, rin_db=0.02, averaging_time_s=0.5e-3, seed=seed)
    seq = Sequencer2D(period_s=T)
    n, t = 0, 0.0

    def step():
        nonlocal t
        t += T
        x, y = seq.setpoint
        seq.update(t, x, y, det.measure(0.0, T), driver_active=True)
    for _ in range(searches):
        seq.release()
        for _ in range(int(seq.p['floor_samples']) + 3):
            step()
        assert seq.state == IDLE
        seq.align()
        for _ in range(LOOK):
            step()
            if seq.state != SEARCHING:
                n += seq.state == PEAKING
                break
    return n


def test_dark_readings_do_not_pass_the_first_light_threshold():
    assert false_first_lights(SEARCHES) <= 2


def test_a_false_first_light_walks_on_instead_of_a_fault():
    """
    Bright readings at the start of the walk, then only dark ones around them: SEARCHING.

    The station's rule (``_false_light``), now the 2-D cross's too: nothing lit in the
    first cross around first light is a noise spike, not light lost (a lockstep rig run
    under load ended in "light lost while peaking around (0.0, 0.0) um").
    """
    det = Detector(noise_floor_w=1e-10, rin_db=0.02, averaging_time_s=0.5e-3, seed=3)
    seq = Sequencer2D(period_s=T)
    t, bright = 0.0, [True]

    def step():
        nonlocal t
        t += T
        x, y = seq.setpoint
        seq.update(t, x, y, 1e-6 if bright[0] else det.measure(0.0, T), driver_active=True)
    bright[0] = False
    seq.release()
    for _ in range(int(seq.p['floor_samples']) + 3):
        step()
    assert seq.align()[0]
    bright[0] = True                    # a spike of light where the walk starts
    for _ in range(LOOK):
        step()
        if seq.state == PEAKING:
            break
    assert seq.state == PEAKING
    bright[0] = False                   # the first cross: all dark
    for _ in range(5000):
        step()
        if seq.state != PEAKING:
            break
    assert seq.state == SEARCHING, (seq.state, seq.fault_reason)
    assert any(e[1] == SEARCHING and e[2] == 'resumed' for e in seq.events)
