# SPDX-License-Identifier: Apache-2.0
"""The realtime simulated plant's sample clock (``plant.dac.DacClock``), without ROS."""

from fiber_align.plant.dac import DacClock, MAX_WAIT_TICKS

T = 1e-3


class Plant:
    """Records the drive (V) of every period it is stepped."""

    def __init__(self):
        self.steps = []

    def step(self, v):
        self.steps.append(v)


def test_on_time_ticks_latch_the_newest_drive_one_period_later():
    dac = DacClock(Plant(), T, 50, 100)
    assert dac.tick(0, 10.0, 10.0, 0, fresh=True) == 0 and dac.plant.steps == []
    dac.write(1.0)
    dac.write(2.0)
    assert dac.tick(0, 10.001, 10.001, 0, fresh=False) == 1
    assert dac.plant.steps == [0.0] and dac.u_latched == 2.0
    assert dac.tick(1, 10.002, 10.002, 0, fresh=False) == 1
    assert dac.plant.steps == [0.0, 2.0] and dac.missed == 1      # no new drive: held


def test_a_late_tick_replays_the_writes_over_the_periods_it_skipped():
    dac = DacClock(Plant(), T, 50, 100)
    dac.tick(0, 0.0, 0.0, 0, fresh=True)
    for v in (1.0, 2.0, 3.0):
        dac.write(v)
    assert dac.tick(0, 0.004, 0.004, 0, fresh=False) == 4
    # the first period the latched drive, then the writes spread over the rest
    assert dac.plant.steps == [0.0, 0.0, 1.0, 2.0] and dac.skipped == 3
    assert dac.u_latched == 3.0                       # the newest, for the next period


def test_a_long_stall_waits_one_tick_for_its_drives():
    dac = DacClock(Plant(), T, 50, 100)
    dac.tick(0, 0.0, 0.0, 0, fresh=True)
    assert dac.tick(0, 0.1, 0.1, 0, fresh=False) is None and dac.plant.steps == []
    assert dac.tick(0, 0.101, 0.101, 0, fresh=False) == 101    # none came: on at once
    assert len(dac.plant.steps) == 101 and dac.u_latched == 0.0


def test_a_long_stall_waits_while_its_drives_still_arrive_then_replays_them_as_a_ramp():
    """The driver's ramp to 0 V, written while the plant slept, arrives over three ticks."""
    dac = DacClock(Plant(), T, 50, 100)
    dac.tick(0, 0.0, 0.0, 0, fresh=True)
    dac.write(52.0)
    dac.tick(0, 0.001, 0.001, 0, fresh=False)               # 52 V latched
    ramp = [52.0 - 2.0 * k for k in range(1, 27)]            # 50 .. 0 V, 2 V a period
    assert dac.tick(1, 0.301, 0.301, 0, fresh=False) is None  # the stall: wait
    for k, (now, part) in enumerate(((0.302, ramp[:10]), (0.303, ramp[10:20]),
                                     (0.304, ramp[20:]))):
        for v in part:
            dac.write(v)
        assert dac.tick(1, now, now, 0, fresh=False) is None, k  # they still come
    steps = dac.tick(1, 0.305, 0.305, 0, fresh=False)          # none new: the catch-up
    assert steps == 304 and len(dac.plant.steps) == 1 + 304
    applied = dac.plant.steps[1:]
    drops = [a - b for a, b in zip(applied, applied[1:])]
    assert applied[0] == 52.0 and applied[-1] == 2.0 and dac.u_latched == 0.0
    assert max(drops) <= 2.0 + 1e-12                         # a ramp, never a step


def test_a_long_stall_waits_for_its_drives_at_most_a_bounded_number_of_ticks():
    dac = DacClock(Plant(), T, 50, 100)
    dac.tick(0, 0.0, 0.0, 0, fresh=True)
    assert dac.tick(0, 0.1, 0.1, 0, fresh=False) is None
    waits = 1
    now = 0.1
    while True:                                  # a writer that never stops
        dac.write(1.0)
        now += T
        if dac.tick(0, now, now, 0, fresh=False) is not None:
            break
        waits += 1
    assert waits == MAX_WAIT_TICKS


def test_a_restart_keeps_the_stamps_on_the_sample_grid():
    dac = DacClock(Plant(), T, 50, 100)
    dac.tick(0, 1.0, 1.0, 5_000_000_000, fresh=True)
    assert dac.wall0_ns == 5_000_000_000
    dac.m0 = None                                   # held, then run again at sample 7
    dac.tick(7, 2.0, 2.0, 6_000_000_000, fresh=False)
    assert dac.wall0_ns + 8 * dac.period_ns == 6_000_000_000
