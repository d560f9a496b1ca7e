# SPDX-License-Identifier: Apache-2.0
"""
The realtime graph's timing model, checked offline (no ROS processes).

The loops below run the nodes' own step rules (:mod:`fiber_align.control.realtime`) with
the control core; the rules' cases one by one: ``test_control_realtime.py``.

In ``realtime`` the plant node latches the newest drive at each tick, so the command
computed from y_k acts over [t_k+1, t_k+2]: one period more delay than lockstep
(``fiber_align.nodes.simulated_actuator``). The controller node feeds the composite
reference model the setpoint one sample old and both nodes lengthen their lead by one
period (``control.realtime.extend_lead``). These tests run that loop with the control core and
check that the 1 kHz gains stay stable with the delay (no separate realtime gain set)
and that a 50 um step settles cleanly, also with missed cycles.
"""

import numpy as np
import pytest

RATE_HZ = 1000.0
T = 1.0 / RATE_HZ


def delayed_loop_radius(kp, ki, slope, delay, omega_n, zeta, alpha):
    """
    Return the largest pole magnitude of the linearised PI loop with ``delay`` periods.

    Plant: ``slope * alpha`` (m/V) times the exactly discretised mode; controller: one
    period of the real :class:`fiber_align.control.pid.Pid` (kd = 0 at 1 kHz) from each
    unit state; the drive computed from y_k is applied ``delay`` periods later than in
    the offline loop.
    """
    from fiber_align.control.pid import Pid
    from fiber_align.design.mode import discretise
    ad, bd = discretise(omega_n, zeta, T)
    pid = Pid(kp, ki, 0.0, T)
    n = 3 + delay

    def f(z):
        x, xd, integ = z[:3]
        hist = list(z[3:])
        pid.reset()
        pid.integral = integ
        u = pid.step(-x)
        if delay:
            ua, hist = hist[0], hist[1:] + [u]
        else:
            ua = u
        xn = ad @ np.array([x, xd]) + bd * alpha * slope * ua
        return np.array([xn[0], xn[1], pid.integral] + hist)
    m = np.column_stack([f(col) for col in np.eye(n)])
    return float(np.max(np.abs(np.linalg.eigvals(m))))


def test_one_period_delay_keeps_the_fuzzy_gain_box_stable():
    """Every gain the fuzzy layer can reach at 1 kHz is stable with the realtime delay."""
    from fiber_align.config import load_params
    from fiber_align.control.fuzzy_pid import FuzzyPid
    from fiber_align.design import load_actuator
    from fiber_align.design.mode import design_dynamics
    from fiber_align.control import realtime as rt
    wn, alpha = design_dynamics(load_actuator())
    fz = FuzzyPid.from_params(load_params('controller.yaml', 'fuzzy_pid_controller'),
                              RATE_HZ)
    (kp_lo, kp_hi), (ki_lo, ki_hi), (kd_lo, kd_hi) = fz.gain_bounds()
    assert kd_lo == kd_hi == 0.0
    delay = rt.REALTIME_EXTRA_DELAY_PERIODS
    zeta = load_params('plant.yaml', 'simulated_actuator')['damping_ratio']
    worst = max(delayed_loop_radius(kp, ki, s, delay, wn, zeta, alpha)
                for kp in (kp_lo, 0.5 * (kp_lo + kp_hi), kp_hi)
                for ki in (ki_lo, 0.5 * (ki_lo + ki_hi), ki_hi)
                for s in (0.5, 0.75, 1.0, 1.5, 2.0))
    assert worst < 0.95, worst


def loop(rate_m_per_s=0.0, accel_m_per_s2=0.0):
    """Return the realtime loop's parts: plant, the nodes' step rules, driver core."""
    from fiber_align.config import load_params
    from fiber_align.control import realtime as rt
    from fiber_align.control.driver import DriverCore
    from fiber_align.simulation import simulate
    plant = simulate.make_plant('default', RATE_HZ, seed=0, noise=True)
    comp, fbc = simulate.build_loop_parts('composite', RATE_HZ, simulate.load_setup())
    rt.extend_lead(comp, T)                 # as the nodes do in realtime
    rt.extend_lead(fbc.reference_filter, T)
    ff_step = rt.CompensatorStep(comp, T, rate_m_per_s, accel_m_per_s2)
    fb_step = rt.ControllerStep(fbc, T, rate_m_per_s, accel_m_per_s2)
    fb_step.setpoint()                      # a setpoint from the start: 0 m, then the step
    drv = DriverCore.from_params(load_params('driver.yaml', 'actuator_driver'))
    return plant, ff_step, fb_step, drv


def stamp(ns):
    """Return a builtin_interfaces/Time for ``ns`` nanoseconds."""
    from builtin_interfaces.msg import Time
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def sample_stamp(k):
    """Return the stamp of sample ``k`` (1 kHz)."""
    return stamp(1_700_000_000_000_000_000 + k * 1_000_000)


def run_realtime_step(target_m=50e-6, n=200, missed_share=0.0, setpoint_one_old=True,
                      seed=1):
    """
    Run the realtime graph's rules for a step to ``target_m`` (m); return x (m) per sample.

    The nodes' own pure parts, called as the nodes call them, one sample at a time: the
    compensator's and the controller's step rules (:mod:`fiber_align.control.realtime`;
    the controller's feeds the setpoint one sample old; ``setpoint_one_old`` False: the
    law gets the latest instead), the driver's input rule
    (:class:`~fiber_align.control.realtime.DriverStep`) and core, and the plant's sample
    clock (:class:`~fiber_align.plant.dac.DacClock`: at each tick the plant advances with
    the drive latched at the previous one, then latches the newest written). A missed
    cycle (probability ``missed_share``) is a drive that reaches the plant after its
    tick: not written before it, so the clock holds the old one.
    """
    from fiber_align.control.realtime import DriverStep
    from fiber_align.plant.dac import DacClock
    rng = np.random.default_rng(seed)
    plant, ff_step, fb_step, drv = loop()
    driver = DriverStep(drv, T)
    dac = DacClock(plant, T, max_catch_up=50, depth=100)
    y = plant.reset()
    dac.tick(0, 0.0, 0.0, 0, fresh=True)        # sample 0: the plant at rest
    out, missed = [], 0
    for k in range(n):
        r = target_m if k >= 5 else 0.0
        now = k * T
        ff_step.drive()
        fb_step.drive()
        ff = ff_step.sample(sample_stamp(k), y, r)
        if setpoint_one_old:
            fb = fb_step.sample(sample_stamp(k), y, r)[0]
        else:
            fb = fb_step.step(r, y)[0]
        assert driver.feedforward(ff, now, True) is None    # the feedback is fresh
        cmd = driver.feedback(fb, now, True)
        v = drv.command(cmd[0], cmd[1], now, cmd[2])
        out.append(plant.x)
        if rng.random() >= missed_share:
            dac.write(v)
        elif dac.n_drive:
            missed += 1
        assert dac.tick(k, now + T, now + T, 0, fresh=False) == 1
        y = plant.y_meas
    assert dac.missed == missed, 'the clock counts the cycles the plant held its drive'
    return np.array(out)


@pytest.mark.parametrize('missed_share', [0.0, 0.1])
def test_realtime_step_settles_without_overshoot(missed_share):
    """50 um: within 0.5 um in 20 ms, overshoot < 1 um, also with 10 % missed cycles."""
    y = run_realtime_step(missed_share=missed_share)
    err = np.abs(y - 50e-6)
    assert np.all(err[5 + 20:] < 0.5e-6)
    assert y.max() < 51e-6


def test_setpoint_one_sample_old_is_what_avoids_the_overshoot():
    """Feeding the reference model the latest setpoint makes the delayed loop overshoot."""
    y_old = run_realtime_step(setpoint_one_old=True)
    y_new = run_realtime_step(setpoint_one_old=False)
    assert y_new.max() - 50e-6 > 5.0 * (y_old.max() - 50e-6 + 0.1e-6)


def test_trajectory_counts_periods_from_stamps_and_limits_the_rate():
    """Periods come from stamp differences; the value moves at most rate * T per period."""
    from fiber_align.control import trajectory as tj
    tr = tj.SetpointTrajectory(T, 2e-3)
    t0 = 1_700_000_000_123_000_000
    assert tr.periods(stamp(t0)) == 1
    assert tr.periods(stamp(t0 + 1_000_000)) == 1
    assert tr.periods(stamp(t0 + 4_000_000)) == 3         # two samples skipped
    assert tr.periods(stamp(t0 + 4_000_000)) == 1         # a repeated stamp still steps
    vals = tr.advance(50e-6, 3)
    np.testing.assert_allclose(vals, [2e-6, 4e-6, 6e-6], rtol=1e-12)
    assert tr.advance(50e-6, 30)[-1] == pytest.approx(50e-6)
    assert tr.advance(10e-6, 1)[0] == pytest.approx(48e-6)
    long = tr.advance(0.0, 1000)                          # a long gap: capped, exact end
    assert len(long) == tj.MAX_CATCH_UP and long[-1] == 0.0
    free = tj.SetpointTrajectory(T, 0.0)                   # no limit
    assert free.advance(80e-6, 1) == [80e-6]


def run_disturbed_step(rate_m_per_s, seed, skip=0.2, missed=0.3, n=200):
    """
    Return y (m) of a realtime 50 um step with timing faults of a non-realtime OS.

    The compensator's step rule skips a share ``skip`` of the samples (the driver then
    reuses its last feedforward; the next answered sample advances the trajectory one
    period); the plant misses a share ``missed`` of the cycles (holds the previous drive).
    """
    rng = np.random.default_rng(seed)
    plant, ff_step, fb_step, drv = loop(rate_m_per_s)
    y = plant.reset()
    latched, ff, out = 0.0, 0.0, []
    for k in range(n):
        target = 50e-6 if k >= 5 else 0.0
        now = k * T
        ff_step.drive()
        fb_step.drive()
        if rng.random() >= skip:
            ff = ff_step.sample(sample_stamp(k), y, target)
        fb = fb_step.sample(sample_stamp(k), y, target)[0]
        v = drv.command(ff, fb, now)
        out.append(plant.x)
        y = plant.step(latched)
        if rng.random() >= missed:
            latched = v
    return np.array(out)


def test_trajectory_makes_skipped_samples_and_missed_cycles_benign():
    """
    With 20 % skipped samples and 30 % missed cycles the 2 mm/s ramp keeps the overshoot small.

    A skipped sample delays the compensator's trajectory by one period against the
    controller's (the node's rule: a stall delays the move, never jumps it), so the
    bound is that of the one-period rule, not of a catch-up.
    """
    from fiber_align.control import trajectory as tj
    seeds = range(8)
    step = [run_disturbed_step(0.0, s).max() for s in seeds]
    ramp = [run_disturbed_step(tj.REALTIME_SETPOINT_RATE_M_PER_S, s).max() for s in seeds]
    assert np.mean(ramp) < 59e-6
    # the integral holds through the path's ramp and its settling (ControllerStep): it
    # does not learn the compensator's lag and give it back past the setpoint
    assert np.mean(ramp) - 50e-6 < 2.5e-6
    assert np.mean(ramp) - 50e-6 < 0.5 * (np.mean(step) - 50e-6)
    y = run_disturbed_step(tj.REALTIME_SETPOINT_RATE_M_PER_S, 0, skip=0.0, missed=0.0)
    assert abs(y[-1] - 50e-6) < 0.1e-6 and y.max() < 50.5e-6


def run_flood_with_late_ticks(late_ticks, late_periods, seed, flood_s=2.0, rest_s=0.5):
    """
    Return the lowest and highest position (m) of a setpoint flood on the composed loop.

    The composed process as it runs: the plant's sample clock
    (:class:`fiber_align.plant.dac.DacClock`) steps the plant and publishes a sample,
    which the compensator's and the controller's step rules answer at once (in-process
    delivery), and the driver's command is written to the clock for its next tick. The
    setpoint rests at 60 um, then a client reverses it between 0 and 80 um about every
    period (now and then twice the same, as a client's sends jitter) for ``flood_s``;
    the ticks numbered in ``late_ticks`` come ``late_periods`` periods late. The graph's
    own rate and acceleration limits of the realtime path (``fiber_align.yaml``).
    """
    from fiber_align.config import load_params
    from fiber_align.plant.dac import DacClock
    g = load_params('fiber_align.yaml', '/**')
    plant, ff_step, fb_step, drv = loop(g['realtime_setpoint_rate_m_per_s'],
                                        g['realtime_setpoint_accel_m_per_s2'])
    rng = np.random.default_rng(seed)
    dac = DacClock(plant, T, 50, 100)
    dac.tick(0, 0.0, 0.0, 0, fresh=True)
    rest, flood = int(rest_s * RATE_HZ), int(flood_s * RATE_HZ)
    target, k, tick, out = 60e-6, 0, 0, []
    for i in range(rest + flood):
        if i >= rest and rng.random() < 0.7:
            target = 0.0 if target > 40e-6 else 80e-6
        tick += late_periods if i in late_ticks else 1
        now = tick * T
        k += dac.tick(k, now, now, 0, fresh=False)
        if i >= rest:
            out.append(plant.x)
        ff_step.drive()
        fb_step.drive()
        ff = ff_step.sample(sample_stamp(k), plant.y_meas, target)
        fb = fb_step.sample(sample_stamp(k), plant.y_meas, target)[0]
        dac.write(drv.command(ff, fb, now))
    return min(out), max(out)


@pytest.mark.parametrize('late_periods', [2, 3, 10])
def test_late_ticks_in_a_setpoint_flood_keep_the_fiber_within_2_um_of_the_range(late_periods):
    """
    A late tick delays both nodes' paths alike, so the feedback never fights the feedforward.

    The controller's path once caught a late sample up while the compensator's waited:
    the fiber went 4-9 um past the 0..80 um a flood commanded. The goal (issue "The
    loop holds under a user's hands"): at most 2 um beyond.
    """
    rng = np.random.default_rng(late_periods)
    for seed in range(4):
        late = set(int(i) for i in rng.integers(600, 2400, 6))
        lo, hi = run_flood_with_late_ticks(late, late_periods, seed)
        assert lo > -2e-6 and hi < 82e-6, (seed, sorted(late), lo, hi)


def test_cycle_stats_report_rate_missed_share_and_latency_per_window():
    """Windowed cycle figures: rate over the window, misses by sample index, percentiles."""
    from fiber_align.control.cycle import CycleStats
    cs = CycleStats(1000.0)
    t0 = 5_000_000_000
    cs.window(t0)                               # the first window starts here
    k0 = cs.index(t0)
    assert cs.index(t0 + 1_000_000 + 3) == k0 + 1, 'stamps k periods apart, rounded'
    # 1 s: 1000 sample periods, every 10th skipped, latency 0.1 ms, one of 1 ms
    for i in range(1, 1001):
        if i % 10:
            cs.record(1e-3 if i == 500 else 1e-4, k0 + i)
    w = cs.window(t0 + 1_000_000_000)
    assert w['cycle.samples'] == 900
    assert w['cycle.achieved_rate_hz'] == pytest.approx(900.0)
    assert w['cycle.missed_share'] == pytest.approx(99 / 999), 'samples k0+1..k0+999'
    assert w['cycle.latency_p50_s'] == pytest.approx(1e-4)
    assert 1e-4 <= w['cycle.latency_p99_s'] < 1e-3, 'one slow sample in 900 is not the p99'
    w = cs.window(t0 + 1_500_000_000)           # idle (plant held): rate 0, no misses
    assert w['cycle.samples'] == 0 and w['cycle.achieved_rate_hz'] == 0.0
    assert 'cycle.missed_share' not in w and 'cycle.latency_p99_s' not in w
    for i in range(2000, 2100):                 # resumed later: counted from its first
        cs.record(1e-4, k0 + i)
    w = cs.window(t0 + 2_000_000_000)
    assert w['cycle.missed_share'] == 0.0


def test_latency_histogram_percentiles_within_its_bin_width():
    """Run-wide percentiles from 1 %-wide log bins: within 0.5 % of sorting every sample."""
    from fiber_align.control.cycle import LatencyHistogram, loop_summary
    h = LatencyHistogram()
    assert h.percentiles((50, 99)) is None
    assert 'latency_p50_s' not in loop_summary(h, 0, 0, 0, 0)
    x = np.random.default_rng(7).lognormal(np.log(4e-5), 0.6, 50_000)
    for v in x:
        h.record(float(v))
    h.record(0.0)                           # a zero (or below 0.1 us) lands in bin 0
    ref = np.percentile(np.append(x, 0.0), (50, 99, 99.9))
    got = h.percentiles((50, 99, 99.9))
    assert np.allclose(got, ref, rtol=0.006, atol=0.0), (got, ref)
    s = loop_summary(h, 60_000, 3, 4, 60_001)
    assert s['latency_n'] == 50_001 and s['latency_max_s'] == x.max()
    assert s['missed_cycles'] == 7 and s['missed_share'] == pytest.approx(7 / 60_000)
    assert s['latency_p99_s'] == pytest.approx(ref[1], rel=0.006)


def test_slack_runs_one_job_after_each_cycle_and_at_once_when_idle():
    """Housekeeping waits for the end of a cycle, one job a cycle; without cycles, now."""
    import math
    from fiber_align.control.cycle import Slack
    ran = []
    sl = Slack(idle_s=10.0)
    sl.submit(lambda: ran.append('idle'))       # no cycle seen yet: at once
    assert ran == ['idle']
    a, b = (lambda: ran.append('a')), (lambda: ran.append('b'))
    sl.after_cycle()
    sl.submit(a)
    sl.submit(b)
    sl.submit(a)                                # already waiting: not twice
    assert ran == ['idle']
    sl.after_cycle()
    assert ran == ['idle', 'a']
    sl.after_cycle()
    sl.after_cycle()
    assert ran == ['idle', 'a', 'b']
    sl.submit(a)
    sl.t_cycle = -math.inf                      # the cycles stopped: the waiting job and
    sl.submit(b)                                # the new one run at once, in order
    assert ran == ['idle', 'a', 'b', 'a', 'b'] and not sl.jobs


def test_slack_waits_for_the_end_of_a_tick_of_several_sample_clocks():
    """The rig's and the station's axes tick in one callback: no job between two axes."""
    from fiber_align.control.cycle import Slack
    ran = []
    sl = Slack(idle_s=10.0)
    sl.after_cycle()
    sl.submit(lambda: ran.append('report'))
    sl.in_tick = True
    for _ in range(4):                          # each axis's answered sample
        sl.after_cycle()
    assert ran == [] and sl.jobs
    sl.end_tick()                               # every axis answered: now
    assert ran == ['report'] and not sl.in_tick and not sl.jobs
