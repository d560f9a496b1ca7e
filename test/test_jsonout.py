# SPDX-License-Identifier: Apache-2.0
"""The one JSON cleaner: numpy and non-finite floats out, and the texts back in."""

import json
import math

import numpy as np

from fiber_align.jsonout import json_clean, json_restore
from fiber_align.simulation.metrics import run_scores


def test_clean_and_restore_round_trip():
    """Non-finite floats become null or text; the text comes back as floats."""
    x = {'a': [np.float64(1.5), math.inf, -math.inf, math.nan], 'n': np.int64(3),
         'trace': [1.0], 'state': 'TRACKING'}
    assert json.loads(json.dumps(json_clean(x, drop=('trace',)))) == {
        'a': [1.5, None, None, None], 'n': 3, 'state': 'TRACKING'}
    back = json_restore(json.loads(json.dumps(json_clean(x, nonfinite_as_text=True))))
    assert back['a'][:3] == [1.5, math.inf, -math.inf] and math.isnan(back['a'][3])
    assert back['state'] == 'TRACKING' and back['trace'] == [1.0]


def test_run_scores_of_analyze_json_with_an_unsettled_step():
    """The demo scores analyze's JSON: an unsettled (infinite) step is the worst one."""
    loop = {'steps': [{'settling_time_s': 0.002, 'overshoot_pct': 0.1, 'rise_time_s': 1e-3},
                      {'settling_time_s': math.inf, 'overshoot_pct': 0.3,
                       'rise_time_s': 2e-3}],
            'tracking': {'rms_error_m': 1e-8, 'max_error_m': 3e-8, 'mean_error_m': 0.0}}
    text = json.loads(json.dumps(json_clean(loop, nonfinite_as_text=True)))
    s = run_scores(json_restore(text))
    assert s == {'settling_time_s': math.inf, 'overshoot_pct': 0.3, 'rise_time_s': 2e-3,
                 'rms_error_m': 1e-8, 'max_error_m': 3e-8}
