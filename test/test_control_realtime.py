# SPDX-License-Identifier: Apache-2.0
"""The realtime step rules of the loop's nodes (``control.realtime``), without ROS."""

import math
import random
from types import SimpleNamespace

import pytest

from fiber_align.control.driver import DriverCore
from fiber_align.control.fuzzy_pid import carry_state, PlainPid
from fiber_align.control.pid import Pid
from fiber_align.control.realtime import CompensatorStep, ControllerStep, DriverStep, PARKED
from fiber_align.control.realtime import INTEGRAL_SETTLE_PERIODS, RECOVERY_S
from fiber_align.control.shaping import design, Lead, ReferenceModel, Shaper
from fiber_align.control.trajectory import DRIVE_STALE_PERIODS, MAX_CATCH_UP
from fiber_align.control.trajectory import SetpointTrajectory

T = 1e-3
T0_NS = 1_700_000_000_000_000_000


def stamp(k):
    """Return the header stamp of sample ``k`` (duck-typed builtin_interfaces/Time)."""
    ns = T0_NS + int(k * 1e6)
    return SimpleNamespace(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class FakeFeedforward:
    """Records calls; step(r) returns 1e6 * r V, start_at(y) returns -y V."""

    def __init__(self):
        self.steps, self.starts = [], []

    def step(self, r):
        self.steps.append(r)
        return 1e6 * r

    def start_at(self, y):
        self.starts.append(y)
        return -y


def answer(st, k, y, target):
    """Answer sample ``k`` as the loop does: the drive comes back after every answer."""
    out = st.sample(stamp(k), y, target)
    st.drive()
    return out


def test_compensator_steps_one_trajectory_period_per_sample_whatever_the_gap():
    st = CompensatorStep(FakeFeedforward(), T, 2e-3)
    st.drive()
    assert st.sample(stamp(0), 0.0, 50e-6) == pytest.approx(2.0)
    # ten periods skipped: still one period of the ramp (a stall delays, never jumps)
    assert st.sample(stamp(10), 0.0, 50e-6) == pytest.approx(4.0)
    assert st.ff.steps == pytest.approx([2e-6, 4e-6])


def test_compensator_rests_while_held_and_after_a_long_gap():
    st = CompensatorStep(FakeFeedforward(), T, 2e-3)
    st.sample(stamp(0), 10e-6, 50e-6)
    st.held = True
    assert st.sample(stamp(1), 12e-6, 50e-6) == -12e-6
    assert st.traj.value == 12e-6 and st.ff.starts == [12e-6]
    st.held = False
    st.sample(stamp(2), 12e-6, 50e-6)
    assert st.ff.steps[-1] == pytest.approx(14e-6)      # on from the rest position
    assert st.sample(stamp(3 + MAX_CATCH_UP), -1.0, 50e-6) == 0.0   # rest at >= 0 m
    assert st.ff.starts[-1] == 0.0


def test_compensator_repeats_the_last_feedforward_while_the_drive_is_stale():
    st = CompensatorStep(FakeFeedforward(), T, 2e-3)
    assert st.sample(stamp(0), 0.0, 50e-6) == pytest.approx(2.0)      # no drive yet
    st.drive()
    for k in range(1, DRIVE_STALE_PERIODS + 1):                     # no drive since
        st.sample(stamp(k), 0.0, 50e-6)
    value = st.traj.value
    late = DRIVE_STALE_PERIODS + 1                                   # one sample more
    assert st.sample(stamp(late), 0.0, 50e-6) == pytest.approx(st.ff.steps[-1] * 1e6)
    assert st.traj.value == value                                    # the trajectory waited
    st.drive()
    st.sample(stamp(late + 1), 0.0, 50e-6)
    assert st.traj.value > value


def test_a_late_sample_is_not_a_stale_drive():
    """The drive's age is counted in samples: one late sample after a drive is fresh."""
    st = CompensatorStep(FakeFeedforward(), T, 2e-3)
    st.drive()
    st.sample(stamp(0), 0.0, 50e-6)
    st.drive()
    st.sample(stamp(10 * DRIVE_STALE_PERIODS), 0.0, 50e-6)          # a late tick
    assert st.traj.value == pytest.approx(4e-6)                      # moved on: 2 periods


def law(period_s=T):
    """Return a PI law with a reference model, as the composite-pid controller."""
    rm = ReferenceModel(Shaper(design('zv', 2 * math.pi * 200.0, 0.03, period_s)),
                        2 * math.pi * 200.0, 0.03, period_s, Lead(period_s, 2e-3, 0.01))
    return PlainPid(Pid(1e4, 1e6, 0.0, period_s, u_min=-30.0, u_max=120.0), rm)


def test_controller_parks_until_the_first_setpoint_and_while_held():
    st = ControllerStep(law(), T, 2e-3)
    assert st.sample(stamp(0), 5e-6, 50e-6) == PARKED     # no setpoint yet
    assert st.setpoint() and not st.setpoint()                  # only the first parks
    assert st.traj.value == 5e-6 and st.ctl.reference_filter.x == 5e-6
    st.drive()
    assert answer(st, 1, 5e-6, 50e-6)[1] == 0.0            # the setpoint one old
    outs = [answer(st, k, 5e-6, 50e-6) for k in range(2, 10)]
    assert outs[0][1] > 0.0 and outs[-1][0] > 0.0
    assert st.ctl.pid.integral == 0.0               # the path's own ramp is not learnt
    k_end = 10 + INTEGRAL_SETTLE_PERIODS - 1
    for k in range(10, k_end):                       # at its setpoint, the integral waits
        answer(st, k, 5e-6, st.traj.value)
    assert st.ctl.pid.integral == 0.0
    answer(st, k_end, 5e-6, st.traj.value)
    assert st.ctl.pid.integral > 0.0                # ... the settling periods, then acts
    st.set_held(True)
    assert st.ctl.pid.integral == 0.0                            # nothing winds up held
    assert st.sample(stamp(k_end + 1), 7e-6, 50e-6) == PARKED
    assert st.traj.value == 7e-6 and st.r_prev == 7e-6           # bumpless resume


def test_controller_holds_its_output_while_the_drive_is_stale():
    st = ControllerStep(law(), T, 2e-3)
    st.setpoint()
    assert st.sample(stamp(0), 0.0, 50e-6)[0] == 0.0        # never heard: held at 0
    st.drive()
    for k in range(1, DRIVE_STALE_PERIODS + 1):
        u = st.sample(stamp(k), 0.0, 50e-6)[0]
    integral, value = st.ctl.pid.integral, st.traj.value
    out = st.sample(stamp(DRIVE_STALE_PERIODS + 1), 0.0, 50e-6)
    assert out[0] == u and math.isnan(out[1])
    assert st.ctl.pid.integral == integral and st.traj.value == value


def test_controller_feeds_the_setpoint_one_sample_old_and_resets_after_a_long_gap():
    st = ControllerStep(law(), T, 0.0)                           # no rate limit
    st.setpoint()
    st.drive()
    assert st.sample(stamp(0), 0.0, 50e-6)[1] == 0.0       # the setpoint one old
    assert st.r_prev == 50e-6                                    # used at the next sample
    assert st.sample(stamp(1), 0.0, 50e-6)[1] == 50e-6
    st.sample(stamp(2 + MAX_CATCH_UP + 1), 3e-6, 50e-6)
    assert st.traj.value == 50e-6 and st.ctl.pid.e_prev is not None


def test_a_late_sample_advances_both_paths_one_period():
    """The compensator's and the controller's paths stay one: a late sample delays both."""
    ff = CompensatorStep(FakeFeedforward(), T, 2e-3)
    fb = ControllerStep(law(), T, 2e-3)
    fb.setpoint()
    for st in (ff, fb):
        st.drive()
    for k in (0, 1, 4, 5, 9):                          # samples 2-3 and 6-8 skipped
        answer(ff, k, 0.0, 50e-6)
        answer(fb, k, 0.0, 50e-6)
        assert fb.traj.value == ff.traj.value
    assert fb.traj.value == pytest.approx(10e-6)       # five samples: five periods


def test_controller_step_without_a_law_is_zero():
    assert ControllerStep(None, T, 2e-3).step(1e-6, 0.0) == (0.0, 1e-6, 0.0, (0.0, 0.0, 0.0))


def driver(timeout=0.05):
    return DriverCore(0.0, 100.0, watchdog_timeout_s=timeout, safe_voltage_v=0.0)


def test_driver_commands_on_feedback_and_on_feedforward_only_while_feedback_is_late():
    rt = DriverStep(driver(), T)
    assert rt.feedforward(10.0, 0.0, True) is None           # no feedback yet
    assert rt.feedback(1.0, 0.0, True) == (10.0, 1.0, None)
    assert rt.feedforward(11.0, 0.001, True) is None          # feedback on time
    assert rt.feedforward(12.0, 0.002, True) == (12.0, 1.0, 0.0)   # late: last fb, its t
    assert rt.feedforward(13.0, 0.06, True) is None           # later than the timeout
    assert DriverStep(driver(), T).feedforward(5.0, 0.0, True, sensorless=True) == \
        (5.0, 0.0, None)


def test_driver_holds_on_a_stale_feedforward_a_latch_and_until_recovered():
    core = driver()
    notes = []
    rt = DriverStep(core, T, notes.append)
    rt.feedforward(10.0, 0.0, True)
    assert rt.feedback(1.0, 0.1, True) is None                # feedforward too old
    core.latched = True
    rt.feedforward(10.0, 0.2, True)
    assert rt.feedback(1.0, 0.2, True) is None
    core.latched, core.tripped = False, True
    t = 0.3
    rt.feedforward(10.0, t, True)
    assert rt.feedback(1.0, t, True) is None and notes        # input back: wait
    while t < 0.3 + RECOVERY_S - T / 2:
        t += T
        rt.feedforward(10.0, t, True)
        out = rt.feedback(1.0, t, True)
    assert out == (10.0, 1.0, None)
    assert rt.feedback(1.0, t, False) is not None             # disabled: no wait


def test_reference_model_reset_to_rests_at_a_position():
    rm = law().reference_filter
    for _ in range(20):
        rm.step(30e-6)
    rm.reset_to(12e-6)
    assert rm.x == 12e-6 and rm.xd == 0.0
    assert rm.step(12e-6) == 12e-6 and rm.step(12e-6) == pytest.approx(12e-6, abs=1e-12)


def test_carry_state_keeps_the_running_pid_state_across_a_retune():
    old, new = law(), law()
    for y in (0.0, 1e-6, 2e-6):
        old.step(50e-6, y)
    carry_state(old, new)
    assert (new.pid.integral, new.pid.deriv, new.pid.e_prev, new.u) == \
        (old.pid.integral, old.pid.deriv, old.pid.e_prev, old.u)
    assert new.reference_filter is old.reference_filter


def test_driver_core_set_limits_keeps_the_state():
    core = DriverCore(0.0, 100.0, slew_rate_v_per_s=1e5, watchdog_timeout_s=0.05)
    core.command(50.0, 0.0, 0.0)
    v = core.v
    core.set_limits({'v_max': 40.0, 'slew_rate_v_per_s': -1.0, 'latch_trips': 2.0})
    assert core.v == v and core.v_max == 40.0 and core.slew == math.inf
    assert core.latch_trips == 2 and core.command(50.0, 0.0, 0.001) == 40.0


def test_setpoint_keeps_the_last_valid_value_and_counts_the_rejected():
    from fiber_align.control.trajectory import Setpoint
    sp = Setpoint(0.0, 100e-6)
    assert sp.take(50e-6) is None and sp.value == 50e-6
    for bad in (math.nan, math.inf, -1e-6, 'x'):
        why = sp.take(bad)
        assert why.startswith('rejected ') and why.endswith('holding 5e-05 m')
    assert sp.value == 50e-6 and sp.rejected == 4


def test_driver_core_start_at_clamps_to_the_limits():
    core = DriverCore(0.0, 100.0)
    assert core.start_at(130.0) == 100.0 and core.v == 100.0
    assert core.start_at(-5.0) == 0.0 and core.start_at(42.0) == 42.0


@pytest.mark.parametrize('accel', [0.4, 4.0])
def test_the_trajectory_limits_speed_and_acceleration_and_stops_at_the_target(accel):
    """A step: an S-shaped ramp within both limits that stops at the target, never past."""
    rate = 2e-3
    tr = SetpointTrajectory(T, rate, accel)
    tr.reset(5e-6)
    path = [5e-6] + [tr.advance(60e-6, 1)[0] for _ in range(200)]
    speed = [(b - a) / T for a, b in zip(path, path[1:])]
    assert max(path) == 60e-6 and path[-1] == 60e-6 and tr.speed == 0.0
    assert max(speed) <= rate * (1 + 1e-9) and min(speed) >= 0.0
    dv = [abs(b - a) for a, b in zip(speed, speed[1:])]
    # every change of speed within the limit; the stop at the target (the fraction of a
    # period left) within twice the limit
    free = [x for k, x in enumerate(dv) if path[k + 2] != 60e-6]
    assert max(free) <= accel * T * (1 + 1e-6)
    assert max(dv) <= 2 * accel * T * (1 + 1e-6)


def test_a_setpoint_reversed_every_period_cannot_reverse_the_motion_every_period():
    """A flood 0 / 80 um at 1 kHz, then bursts: never past the targets, speed changes bounded."""
    accel = 0.4
    tr = SetpointTrajectory(T, 2e-3, accel)
    tr.reset(40e-6)
    path = [40e-6]
    for k in range(10000):
        path += tr.advance(0.0 if k % 2 else 80e-6, 1)
    rng = random.Random(3)
    for _ in range(2000):
        target = rng.choice((0.0, 80e-6))
        path += [tr.advance(target, 1)[0] for _ in range(rng.randint(1, 40))]
    assert 0.0 <= min(path) and max(path) <= 80e-6
    speed = [(b - a) / T for a, b in zip(path, path[1:])]
    dv = [abs(b - a) for a, b in zip(speed, speed[1:])]
    # every change of speed within the limit (twice it into a stop: the fraction of a
    # period left before the target)
    free = [x for k, x in enumerate(dv) if path[k + 1] not in (0.0, 80e-6)
            and path[k + 2] not in (0.0, 80e-6)]
    assert len(free) > 0.5 * len(dv) and max(free) <= accel * T * (1 + 1e-6)
    assert max(dv) <= 2 * accel * T * (1 + 1e-6)


def test_without_an_acceleration_limit_the_trajectory_is_the_plain_rate_limit():
    tr = SetpointTrajectory(T, 2e-3)
    assert tr.advance(5e-6, 4) == pytest.approx([2e-6, 4e-6, 5e-6, 5e-6], abs=1e-15)
    assert tr.advance(0.0, 1) == pytest.approx([3e-6], abs=1e-15)


def test_the_compensators_lead_never_predicts_past_the_setpoint():
    """The realtime step bounds the feedforward's lead by the path's target."""
    from fiber_align.control.feedforward import Feedforward
    ff = Feedforward(gain_v_per_m=1e6, lead=Lead(T, 3 * T, 1e3))
    st = CompensatorStep(ff, T, 2e-3, 0.0)
    st.drive()
    refs = []
    for k in range(60):
        answer(st, k, 0.0, 50e-6)
        refs.append(ff.r_shaped)
    assert max(refs) == pytest.approx(50e-6, abs=1e-15) and refs[-1] == 50e-6
    assert refs[10] == pytest.approx(11 * 2e-6 + 3 * T * 2e-3, rel=1e-9)   # mid-ramp: led


def test_a_streamed_reference_is_led_freely():
    """Setpoints that move a little every period (a scenario, a dither): not bounded."""
    from fiber_align.control.feedforward import Feedforward
    ff = Feedforward(gain_v_per_m=1e6, lead=Lead(T, 3 * T, 1e3))
    st = CompensatorStep(ff, T, 2e-3, 0.4)
    st.drive()
    speed = 1e-4                                    # m/s: 0.1 um a period
    for k in range(30):
        answer(st, k, 0.0, speed * T * (k + 1))
    assert not st.traj.ramping and st.traj.value == pytest.approx(speed * T * 30, rel=1e-12)
    assert ff.r_shaped == pytest.approx(speed * T * 30 + 3 * T * speed, rel=1e-9)
