# SPDX-License-Identifier: Apache-2.0
"""Tests of :mod:`fiber_align.graph.params`: ``-p`` overrides as ``bringup`` takes them."""

import pytest

from fiber_align.config import ConfigError
from fiber_align.graph.params import parse_overrides


def test_overrides_are_yaml_values_per_node_and_star_star_is_every_node():
    ov = parse_overrides(['simulated_actuator:noise_rms_m:=0.0', '**:rate_hz:=500',
                          'x/actuator_driver:v_max:=80.5', '/**:sync_mode:=lockstep'],
                         {'bag_recorder': {'storage': 'mcap'}})
    assert ov == {'bag_recorder': {'storage': 'mcap'},
                  'simulated_actuator': {'noise_rms_m': 0.0},
                  '/**': {'rate_hz': 500, 'sync_mode': 'lockstep'},
                  'x/actuator_driver': {'v_max': 80.5}}


@pytest.mark.parametrize('item, why', [('rate_hz:=5', 'NODE:NAME:=VALUE'),
                                       ('node:name=5', 'NODE:NAME:=VALUE'),
                                       ('node:name:=[1, 2', 'not a YAML value')])
def test_an_item_that_is_not_node_name_value_is_refused_with_its_text(item, why):
    with pytest.raises(ConfigError, match=why):
        parse_overrides([item], {})
