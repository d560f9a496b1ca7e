# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.plant.dac`: the drive replayed over a stall of the plant."""

import pytest

from fiber_align.plant.actuator import SimulatedActuator
from fiber_align.plant.dac import replay_edges


def test_no_write_holds_the_previous_value():
    """Nothing written during the stall: every edge latches the value before it."""
    assert replay_edges(52.0, [], 4) == [52.0] * 4


def test_one_period_latches_the_newest_write():
    """An on-time tick (n = 1) keeps the DAC's rule: the last write before the edge wins."""
    assert replay_edges(1.0, [2.0, 3.0, 4.0], 1) == [4.0]


@pytest.mark.parametrize('m,n', [(1, 1), (3, 3), (5, 7), (26, 300), (7, 5), (40, 3)])
def test_writes_are_spread_in_order_and_end_at_the_newest(m, n):
    """Order kept, the newest last, none skipped while m <= n, as few as possible else."""
    writes = [float(i) for i in range(1, m + 1)]
    out = replay_edges(0.0, writes, n)
    assert len(out) == n and out[-1] == writes[-1]
    assert all(b >= a for a, b in zip(out, out[1:]))
    seen = sorted(set(out) - {0.0})
    if m <= n:
        assert seen == writes
    else:
        gaps = [b - a for a, b in zip([0.0] + out, out)]
        assert max(gaps) <= -(-m // n)


def test_bad_edge_count_is_refused():
    """Fewer than one edge is an error, not an empty replay."""
    with pytest.raises(ValueError):
        replay_edges(0.0, [1.0], 0)


def test_a_replayed_ramp_does_not_ring_the_plant_the_way_a_step_does():
    """
    The watchdog's ramp 52 V -> 0 V (2 V a period) written during a 300-period stall.

    Replayed over the stall the plant goes no lower than under the ramp as the driver
    made it (50 periods at 52 V, 26 ramp periods, 0 V) give or take the ringing of one
    2 V step (about 1 um); holding the old value and applying only the newest write (0 V)
    afterwards steps 52 V down and rings the bending mode some 25 um below (the failure
    of ``test_nodes_realtime.py``: -20 um).
    """
    ramp = [52.0 - 2.0 * i for i in range(1, 27)]

    def lowest(drives):
        p = SimulatedActuator.from_config()
        p.reset()
        for _ in range(3000):
            p.step(52.0)
        assert p.position_m > 40e-6
        low = p.position_m
        for v in drives:
            p.step(v)
            low = min(low, p.position_m)
        return low

    made = lowest([52.0] * 50 + ramp + [0.0] * 274)
    replayed = lowest(replay_edges(52.0, ramp, 300) + [0.0] * 50)
    newest_only = lowest([52.0] * 299 + [0.0] * 51)
    assert replayed >= made - 1e-6, (replayed, made)
    assert newest_only < made - 10e-6, (newest_only, made)
