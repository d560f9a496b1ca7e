# SPDX-License-Identifier: Apache-2.0
"""The meaning checks of the nodes' parameters (``graph.checks``), pure."""

import pytest

from fiber_align.config import config_path, load_params
from fiber_align.control.factory import check_param, CONTROLLERS
from fiber_align.design import design_dynamics, load_actuator
from fiber_align.graph import checks
from fiber_align.hysteresis.pi import PIModel

ALPHA = design_dynamics(load_actuator('actuator.yaml'))[1]     # m/V
RANGE = (0.0, 90e-6)                                            # the shipped setpoint range


def limits(u_min, u_max, controller='composite'):
    return checks.feedback_limits(u_min, u_max, controller, *RANGE, ALPHA)


def test_the_shipped_limits_pass_for_every_controller():
    p = load_params('controller.yaml', 'fuzzy_pid_controller')
    for c in CONTROLLERS:
        assert limits(p['u_min'], p['u_max'], c) is None, c


@pytest.mark.parametrize('controller', ['composite', 'composite-pid', 'pid', 'fuzzy'])
def test_u_max_below_zero_is_refused_naming_it_and_the_allowed_values(controller):
    why = limits(-100.0, -50.0, controller)
    assert why.startswith('u_max=-50 V') and 'allowed: u_max' in why


def test_feedback_alone_must_reach_the_voltage_of_the_top_setpoint():
    need = RANGE[1] / ALPHA
    assert 70.0 < need < 80.0                   # 90 um at about 1.2 um/V
    why = limits(-100.0, need - 1.0, 'fuzzy')
    assert why and 'u_max >= %.1f V' % need in why and 'setpoint_max_m 90.0 um' in why
    assert limits(-100.0, need + 0.1, 'fuzzy') is None
    assert limits(-100.0, need - 1.0, 'composite') is None      # the feedforward drives
    assert 'u_min <= 0.0 V' in limits(5.0, 100.0, 'pid')


def test_u_min_at_or_above_u_max_is_refused():
    for lo, hi in ((10.0, 10.0), (20.0, 10.0)):
        why = limits(lo, hi)
        assert why.startswith('u_min=%g V must be below u_max' % lo)
        assert 'allowed: u_min < u_max' in why


def test_composite_needs_a_correction_both_ways():
    assert 'allowed: u_min < 0 V' in limits(0.0, 100.0)
    assert limits(-1.0, 1.0) is None


def test_no_feedback_law_no_limit_check():
    assert limits(-50.0, -100.0, 'feedforward') is not None     # u_min >= u_max still
    assert limits(-100.0, -50.0, 'feedforward') is None
    assert limits(-100.0, -50.0, 'open-loop') is None


def _controller_params(**changes):
    p = load_params('controller.yaml', 'fuzzy_pid_controller')
    p.update(changes)
    return p


def test_gain_rates_zero_is_a_range_not_a_math_domain_error():
    why = checks.controller_values({'gain_rates_hz': [0.0]},
                                   _controller_params(gain_rates_hz=[0.0]), 'composite',
                                   *RANGE, ALPHA)
    assert why == 'gain_rates_hz=0.0 is out of range [1, 1e+06]'
    assert check_param('gain_rates_hz', [1000.0, 10000.0]) is None


def test_gain_lists_must_have_one_entry_per_rate():
    p = _controller_params(gain_rates_hz=[1000.0])
    why = checks.controller_values({'gain_rates_hz': [1000.0]}, p, 'composite', *RANGE,
                                   ALPHA)
    assert why.startswith('pid.kp has 2 entries for 1 gain_rates_hz')
    assert 'one entry per rate' in why


@pytest.mark.parametrize('name,value', [('anti_windup', 'clamp'),
                                        ('composite_feedback_reference', 'modle')])
def test_choice_parameters_name_the_allowed_values(name, value):
    why = checks.controller_values({name: value}, _controller_params(**{name: value}),
                                   'composite', *RANGE, ALPHA)
    assert why.startswith('%s=%r: allowed: ' % (name, value))


def test_model_file_must_be_a_readable_invertible_model(tmp_path):
    assert checks.model_file('') is None
    assert checks.model_file('models/compensator_model.yaml') is None   # a config name
    assert checks.model_file(str(config_path('hysteresis_paper.yaml'))) is None
    why = checks.model_file('/nonexistent.yaml')
    assert why.startswith("model_file='/nonexistent.yaml': no readable file there")
    assert "allowed: '' for the inline model" in why
    bad = tmp_path / 'bad.yaml'
    bad.write_text('a: [1, 2\n')
    assert 'holds no usable PI model' in checks.model_file(str(bad))
    other = tmp_path / 'other.yaml'
    other.write_text('x:\n  ros__parameters:\n    y: 1\n')
    assert 'holds no usable PI model' in checks.model_file(str(other))


def test_inline_model_must_be_invertible():
    m = PIModel.load('models/compensator_model.yaml')
    assert checks.pi_model(m.thresholds, m.weights) is None
    assert 'entries' in checks.pi_model([0.0, 1.0], [1e-6])
    assert checks.pi_model([1.0, 0.0], [1e-6, 1e-7]).startswith('thresholds_v=')
    assert checks.pi_model([0.0, 1.0], [-1e-6, 1e-7]).startswith('weights_m_per_v=')


def test_protections_off_are_named():
    p = load_params('driver.yaml', 'actuator_driver')
    assert checks.protections_off(p) == {}
    off = checks.protections_off(dict(p, watchdog_timeout_s=0.0, latch_trips=0))
    assert set(off) == {'watchdog_timeout_s', 'latch_trips'}
    assert off['watchdog_timeout_s'].startswith('watchdog_timeout_s=0.0: the watchdog is off')
    assert 'slew_rate_v_per_s' in checks.protections_off(dict(p, slew_rate_v_per_s=-1.0))


@pytest.mark.parametrize('key,value,text', [
    ('output_scale', [0.8, 0.8], 'fuzzy.output_scale has 2 entries (allowed: 3'),
    ('surface_intervals', 7, 'fuzzy.surface_intervals=7 (allowed: 0, the exact'),
    ('e_domain', [12.0, -12.0], 'fuzzy.e_domain=[12.0, -12.0] (allowed: [lo, hi]')])
def test_fuzzy_section_sizes_name_the_parameter_and_the_allowed_values(key, value, text):
    p = _controller_params()
    p['fuzzy'] = dict(p['fuzzy'], **{key: value})
    why = checks.controller_values({'fuzzy.' + key: value}, p, 'composite', *RANGE, ALPHA)
    assert why.startswith(text), why
    assert checks.fuzzy_values(_controller_params()['fuzzy']) is None
