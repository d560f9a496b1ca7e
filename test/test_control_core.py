# SPDX-License-Identifier: Apache-2.0
"""Tests of the control core: fuzzy inference, PID, driver, shaping, stability."""

import itertools
import math

import numpy as np
import pytest

from fiber_align.config import load_params
from fiber_align.control.driver import DriverCore
from fiber_align.control.fuzzy import FuzzyInference, reference_mamdani
from fiber_align.control.fuzzy_pid import FuzzyPid
from fiber_align.control.pid import Pid
from fiber_align.control.shaping import design, sampled_pole
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics
from fiber_align.simulation.metrics import step_metrics, tracking_metrics
from fiber_align.simulation.tuning import spectral_radius


def _fis():
    """Return the configured fuzzy system."""
    return FuzzyInference.from_params(
        load_params('controller.yaml', 'fuzzy_pid_controller')['fuzzy'])


def test_fuzzy_matches_reference_mamdani_within_1e3_of_span():
    """Closed form equals a 10,001-point Mamdani to 1e-3 of each output span."""
    fis = _fis()
    rng = np.random.default_rng(7)
    pts = list(rng.uniform([-14, -22], [14, 22], (150, 2)))
    pts += list(itertools.product(np.linspace(-12, 12, 7), np.linspace(-20, 20, 7)))
    spans = [hi - lo for lo, hi in fis.out_domains]
    worst = 0.0
    for e, ec in pts:
        a = fis.evaluate(e, ec)
        b = reference_mamdani(fis, e, ec, 10001)
        worst = max(worst, max(abs(x - y) / s for x, y, s in zip(a, b, spans)))
    assert worst < 1e-3


def test_fuzzy_peak_cell_gives_rule_consequent_centroid():
    """At E = NB, EC = NB only rule (NB, NB) fires fully: dkp = PB half-triangle centroid."""
    fis = _fis()
    dkp, dki, dkd = fis.evaluate(-12.0, -20.0)
    # PB is a half triangle on [4, 6] peaking at 6: centroid 4 + 2 * 2 / 3
    assert dkp == pytest.approx(4.0 + 4.0 / 3.0, abs=1e-12)
    assert dki == pytest.approx(-(4.0 - 4.0 / 3.0 * 4.0 / 6.0 * 1.0) - 0.0, abs=1.0)
    assert fis.evaluate(-100.0, -100.0) == fis.evaluate(-12.0, -20.0)  # clamped


def test_fuzzy_nan_raises():
    """A NaN input is refused by the inference (the PID layer holds instead)."""
    with pytest.raises(ValueError):
        _fis().evaluate(math.nan, 0.0)


def test_pid_antiwindup_limits_integral():
    """With the output clamped the back-calculated integral stays at the limit."""
    pid = Pid(0.0, 1e9, 0.0, 1e-3, u_min=-10, u_max=10)
    for _ in range(100):
        u = pid.step(1e-3)
    assert u == 10.0 and pid.integral == pytest.approx(10.0)
    # recovers immediately when the error reverses
    assert pid.step(-1e-6) < 10.0


def test_pid_nan_holds_output_and_counts():
    """A NaN error holds the last output and is counted."""
    pid = Pid(1e5, 1e8, 0.0, 1e-3, u_min=-100, u_max=100)
    u = pid.step(1e-5)
    assert pid.step(math.nan) == u and pid.nan_count == 1 and pid.held


def test_driver_clamp_slew_watchdog():
    """Check that the driver clamps, slew-limits, trips the watchdog and counts each event."""
    d = DriverCore(v_min=0.0, v_max=100.0, slew_rate_v_per_s=1e4, watchdog_timeout_s=0.01)
    assert d.command(50.0, 0.0, 0.0) == 50.0
    assert d.command(200.0, 0.0, 1e-3) == 60.0  # clamp to 100 then slew 10 V per ms
    assert d.saturation_count == 1 and d.slew_count == 1
    assert d.command(-5.0, 0.0, 1.0) == 0.0
    assert d.tick(1.005) == 0.0 and d.watchdog_count == 0
    d.command(50.0, 0.0, 2.0)
    assert d.tick(2.1) == 50.0 and d.watchdog_count == 1    # the trip: the ramp starts
    assert d.tick(2.101) < 50.0
    assert d.command(math.nan, 0.0, 2.2) == d.v and d.nan_count == 1


def test_driver_watchdog_latches_after_three_trips_in_the_window():
    """Three trips within 10 s latch the safe voltage; commands then change nothing."""
    d = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05, latch_trips=3,
                   latch_window_s=10.0)
    t = 0.0
    for trip in range(3):
        assert not d.latched
        d.command(60.0, 0.0, t)            # input flows, then stops for 0.1 s
        t += 0.1
        d.tick(t)
        assert d.watchdog_count == trip + 1
        t += 0.01
    assert d.latched and d.v == 0.0
    assert d.command(60.0, 0.0, t) == 0.0 and d.command(80.0, 0.0, t + 1) == 0.0
    d.rearm()
    assert not d.latched and d.command(60.0, 0.0, t + 2) == 60.0


def test_driver_trips_spread_beyond_the_window_do_not_latch():
    """Trips more than latch_window_s apart never latch."""
    d = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05, latch_trips=3,
                   latch_window_s=10.0)
    for k in range(6):
        t = 6.0 * k
        d.command(60.0, 0.0, t)
        d.tick(t + 0.1)
    assert d.watchdog_count == 6 and not d.latched


@pytest.mark.parametrize('rate', [1000.0, 10000.0])
@pytest.mark.parametrize('kind', ['zv', 'zvd'])
def test_shaper_taps_cancel_sampled_mode(rate, kind):
    """Shaper taps are non-negative, sum to 1 and vanish at the sampled pole."""
    wn, _ = design_dynamics(load_actuator())
    h = design(kind, wn, 0.03, 1.0 / rate)
    p = sampled_pole(wn, 0.03, 1.0 / rate)
    assert np.all(h >= 0) and h.sum() == pytest.approx(1.0)
    assert abs(sum(hi * p ** (-i) for i, hi in enumerate(h))) < 1e-9


@pytest.mark.parametrize('rate', [1000.0, 10000.0])
def test_every_fuzzy_gain_set_is_stable(rate):
    """
    Every gain set the fuzzy layer can produce keeps the linearised loop stable.

    Checked on a 5 x 5 x 5 grid of the reachable (kp, ki, kd) box (corners included) and
    for plant slopes from 0.5 to 1.5 times the design alpha (hysteresis changes it).
    """
    wn, alpha = design_dynamics(load_actuator())
    fp = FuzzyPid.from_config(rate)
    (kp0, kp1), (ki0, ki1), (kd0, kd1) = fp.gain_bounds()
    fd = -math.log(fp.pid.deriv_pole) / (2 * math.pi / rate) if fp.pid.deriv_pole else 0.0
    worst = 0.0
    for kp, ki, kd in itertools.product(np.linspace(kp0, kp1, 5), np.linspace(ki0, ki1, 5),
                                        np.linspace(kd0, kd1, 5)):
        for s in (0.5, 1.0, 1.5):
            worst = max(worst, spectral_radius(kp, ki, kd, fd, 1.0 / rate, wn, 0.03,
                                               alpha * s))
    assert worst < 1.0


def test_metrics_on_known_signals():
    """Step and tracking metrics of analytic signals."""
    t = np.linspace(0, 1, 1001)
    y = 1 - np.exp(-t / 0.1)
    m = step_metrics(t, y, 1.0)
    assert m['overshoot_pct'] == 0.0
    assert m['settling_time_s'] == pytest.approx(0.1 * math.log(50), abs=2e-3)
    assert m['rise_time_s'] == pytest.approx(0.1 * math.log(9), abs=2e-3)
    tm = tracking_metrics(t, np.zeros_like(t), np.sin(2 * np.pi * t), skip_s=0.0)
    assert tm['max_error_m'] == pytest.approx(1.0, abs=1e-4)
    assert tm['rms_error_m'] == pytest.approx(math.sqrt(0.5), abs=1e-3)


def test_driver_field_limits_agree_with_the_design_and_hold_the_defaults():
    """driver.yaml's forward limit is actuator.yaml's; its defaults lie inside both."""
    from fiber_align.config import load_params
    from fiber_align.design import load_actuator
    d = load_params('driver.yaml', 'actuator_driver')
    a = load_actuator()
    assert d['field_limit_v'] == pytest.approx(a.field_limit_v, rel=1e-12)
    rev = -d['depoling_fraction'] * d['coercive_field_v']
    for k in ('v_min', 'v_max', 'safe_voltage_v'):
        assert rev <= d[k] <= d['field_limit_v'], k


def test_driver_ramps_to_the_safe_voltage_at_its_own_rate_from_the_trip():
    """A trip long after the last command still ramps at safe_ramp_rate_v_per_s."""
    d = DriverCore(v_min=0.0, v_max=100.0, slew_rate_v_per_s=5e5, watchdog_timeout_s=0.05,
                   safe_ramp_rate_v_per_s=2000.0)
    d.command(52.0, 0.0, 0.0)
    assert d.tick(0.06) == 52.0 and d.tripped          # trips at 60 ms: the ramp starts
    steps = [d.tick(0.06 + 1e-3 * k) for k in range(1, 40)]
    assert steps[0] == pytest.approx(50.0) and max(-np.diff(steps)) <= 2.0 + 1e-9
    assert steps[-1] == 0.0 and steps[24] > 0.0        # 52 V take 26 ms


def test_driver_ramp_after_a_stall_of_the_caller_goes_on_by_one_period():
    """A 20 ms stall mid-ramp moves the output by one period's step, not by 40 V."""
    d = DriverCore(v_min=0.0, v_max=100.0, slew_rate_v_per_s=5e5, watchdog_timeout_s=0.05,
                   safe_ramp_rate_v_per_s=2000.0, ramp_period_s=1e-3)
    d.command(52.0, 0.0, 0.0)
    d.tick(0.06)                                        # the trip: the ramp starts
    assert d.tick(0.061) == pytest.approx(50.0)
    assert d.tick(0.081) == pytest.approx(48.0)         # 20 ms later: 2 V, one period
    uncapped = DriverCore(v_min=0.0, v_max=100.0, slew_rate_v_per_s=5e5,
                          watchdog_timeout_s=0.05, safe_ramp_rate_v_per_s=2000.0)
    uncapped.command(52.0, 0.0, 0.0)
    uncapped.tick(0.06)
    uncapped.tick(0.061)
    assert uncapped.tick(0.081) == pytest.approx(10.0)  # what the cap prevents: a step


def test_driver_watchdog_counts_from_the_stalest_input_of_a_command():
    """Commands on fresh feedforward with the last, late feedback still trip on time."""
    d = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05)
    d.command(10.0, 1.0, 0.0)                           # the feedback's last arrival: 0 s
    for k in range(1, 50):                              # feedforward-clocked, 1 ms apart
        t = 1e-3 * k
        assert d.command(10.0 + 0.1 * k, 1.0, t, t_input=0.0) == pytest.approx(11.0 + 0.1 * k)
        assert d.tick(t) == d.v and not d.tripped
    d.tick(0.051)
    assert d.tripped and d.watchdog_count == 1          # 50 ms after the feedback, as before
    fresh = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05)
    fresh.command(10.0, 1.0, 0.0)
    fresh.command(10.0, 1.0, 0.049)                     # without t_input: counts from t
    fresh.tick(0.051)
    assert not fresh.tripped


def test_driver_watchdog_restarts_at_activation():
    """The time without commands while inactive does not trip the watchdog afterwards."""
    d = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05)
    d.command(10.0, 0.0, 0.0)
    d.restart_watchdog()                    # an activation 1 s later
    assert d.tick(1.0) == 10.0 and not d.tripped and d.watchdog_count == 0
    d.command(12.0, 0.0, 1.001)
    d.tick(1.06)
    assert d.tripped and d.watchdog_count == 1      # from the next command on, as ever


def test_driver_watchdog_does_not_count_the_time_it_was_stalled_itself():
    """A tick long after the last one (the machine stopped) takes that time off the silence."""
    d = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05, ramp_period_s=1e-3)
    t = 0.0
    for k in range(100):                        # input and watchdog every period
        t = 1e-3 * k
        d.command(40.0, 0.0, t)
        d.tick(t)
    last = t
    # everything stopped for 0.1 s (two timeouts): on waking, the input is not late yet
    assert d.tick(last + 0.1) == 40.0 and not d.tripped
    d.command(41.0, 0.0, last + 0.1005)         # and it comes: no trip, no ramp
    assert not d.tripped and d.watchdog_count == 0
    # input gone while the watchdog runs: 30 ms awake, a 0.1 s stall, then 20 ms more
    t0 = last + 0.1005
    awake = [t0 + 1e-3 * k for k in range(1, 31)] + [t0 + 0.13 + 1e-3 * k for k in range(25)]
    tripped_at = None
    for t in awake:
        d.tick(t)
        if d.tripped and tripped_at is None:
            tripped_at = t
    assert tripped_at is not None and d.watchdog_count == 1
    # 50 ms of the watchdog's own time after the input stopped (the stall's 0.1 s excluded)
    assert tripped_at - t0 - 0.1 == pytest.approx(0.05, abs=1.5e-3)


def test_driver_hold_takes_the_input_but_ramps_on_to_safe():
    """An axis held for another's trip: its input is back (not tripped), output ramps to safe."""
    d = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05,
                   safe_ramp_rate_v_per_s=100.0, ramp_period_s=0.01)
    d.command(50.0, 0.0, 0.0)
    d.tick(0.1)
    assert d.tripped and d.watchdog_count == 1
    v = d.hold(0.11)
    assert not d.tripped and v < 50.0 and d.v == v
    assert d.tick(0.12) == v and not d.tripped and d.watchdog_count == 1
    assert d.hold(0.13) < v                                 # still on its way to 0 V
    assert d.command(50.0, 0.0, 0.14) > d.safe              # the other is back: follow
    # a latched watchdog stays latched whatever a hold says
    d2 = DriverCore(v_min=0.0, v_max=100.0, watchdog_timeout_s=0.05, latch_trips=1)
    d2.command(50.0, 0.0, 0.0)
    d2.tick(0.1)
    assert d2.latched
    d2.hold(0.11)
    assert d2.latched and d2.command(50.0, 0.0, 0.12) == 0.0
