# SPDX-License-Identifier: Apache-2.0
"""The array's report section (``fiber_align.analysis.array_run``) from the model's message."""

import math

import numpy as np
import pytest

from fiber_align.analysis import array_run as ar
from fiber_align.analysis.report import metrics_rows
from fiber_align.plant import array_optics as ao


@pytest.fixture(scope='module')
def link():
    return ao.ArrayLink.from_params(seed=3, chip_roll_rad=-6e-3, layout_seed=3)


def _row(c, pose_, t_s=1.25):
    return c.model(t_s, ao.actuators(*pose_, c.roll_arm_m))


def test_the_model_s_message_has_its_labels(link):
    c = link.coupling
    row = _row(c, (30e-6, 31e-6, 1e-3))
    assert len(row) == len(ao.model_labels(c.n)) == 7 + 2 * c.n
    v = dict(zip(ao.model_labels(c.n), row))
    assert v['t_s'] == 1.25 and v['roll_rad'] == pytest.approx(1e-3, abs=1e-15)
    assert [v['best_' + k] for k in ao.POSE_LABELS] == list(c.best())


@pytest.mark.parametrize('offset', [(0.0, 0.0, 0.0), (0.4e-6, -0.3e-6, 0.0),
                                    (0.0, 0.0, 2e-3), (1e-6, 0.5e-6, -3e-3)])
def test_each_channel_s_loss_follows_from_the_formula_and_the_worst_is_the_json_s(
        link, offset):
    c = link.coupling
    pose_ = tuple(b + d for b, d in zip(c.best(), offset))
    m = ar.array_metrics(ao.model_labels(c.n), _row(c, pose_), t0_s=0.25,
                         align={'time_to_peak_s': 0.051, 'peak_samples': 51})
    now = ao.couplings(pose_, c.chip, c.u_m, c.offsets_m, c.gains, c.mode_radius_m)
    best = ao.couplings(c.best(), c.chip, c.u_m, c.offsets_m, c.gains, c.mode_radius_m)
    assert m['loss_db'] == pytest.approx(list(10 * np.log10(best / now)), abs=1e-9)
    assert m['coupling_db'] == pytest.approx(list(10 * np.log10(now)), abs=1e-9)
    assert m['worst_channel'] == int(np.argmin(now)) + 1
    assert m['worst_channel_loss_db'] == pytest.approx(ao.worst_channel_loss_db(
        pose_, c.best(), c.chip, c.u_m, c.offsets_m, c.gains, c.mode_radius_m), abs=1e-9)
    assert (m['worst_channel_loss_db'] <= 1e-9) == (offset == (0.0, 0.0, 0.0))
    assert m['t_s'] == 1.0 and m['time_to_aligned_s'] == 0.051 and m['samples'] == 51
    assert m['pose']['roll_rad'] == pytest.approx(pose_[2], abs=1e-12)


def test_the_report_has_the_array_s_rows(link):
    c = link.coupling
    pose_ = (c.best()[0], c.best()[1], c.best()[2] + 1e-3)
    m = ar.array_metrics(ao.model_labels(c.n), _row(c, pose_))
    rows = metrics_rows({'kind': 'alignment', 'metrics': {'array': m}})
    text = {(a, b): v for a, b, v in rows}
    want = '%.4g mrad' % (pose_[2] * 1e3)
    assert text[('array', 'roll found')].startswith(want)
    assert 'off by 1 mrad' in text[('array', 'roll found')]
    assert text[('array', 'samples')] == 'n/a'
    per = [r for r in rows if r[0] == 'array channels']
    assert len(per) == c.n and '(measured)' in per[0][1] and '(measured)' in per[-1][1]
    assert sum('(measured)' in r[1] for r in per) == 2


def test_a_message_that_is_not_the_model_s_is_refused_by_name():
    with pytest.raises(ValueError, match='not the model'):
        ar.array_metrics(('error', 'kp', 'ki'), [0.0, 1.0, 2.0])
    labels = ao.model_labels(4)
    with pytest.raises(ValueError, match='not the model'):
        ar.array_metrics(labels[:-1], [1.0] * (len(labels) - 1))
    m = ar.array_metrics(labels, [0.0] * 7 + [0.0] * 4 + [1.0] * 4)    # no light: inf dB
    assert math.isinf(m['worst_channel_loss_db'])
