# SPDX-License-Identifier: Apache-2.0
"""
The fiber array's section of a run report, from the model's ``array_model`` stream.

``simulated_array_optics`` publishes, every ``model_period_s``, the array's pose, the best
joint pose and every channel's coupling there and at the best pose
(:func:`fiber_align.plant.array_optics.model_labels`). The section takes the last message
of the run: the pose the alignment left the array in (the roll found), each channel's
coupling and its loss against its coupling at the best joint pose (the worst of them is
the offline JSON's ``worst_channel_loss_db``), with the alignment's time and samples.
SI units (m, rad, s; dB for ratios); the report's rows: :func:`fiber_align.analysis.
report.array_rows`.
"""

import numpy as np

from fiber_align.plant.array_optics import measured, model_labels, POSE_LABELS as POSE


def array_metrics(labels, row, t0_s=0.0, align=None):
    """
    Return the array's figures (SI) from one ``array_model`` message.

    :param labels: the message's labels (``t_s``, ``x_m`` ... ``best_coupling_N``).
    :param row: its values, in the order of ``labels``.
    :param t0_s: the run's first sample's stamp (s): ``t_s`` is given from it.
    :param align: the run's ``metrics.align`` (time to peak, peak samples), or None.
    :raises ValueError: labels that are not the model's.
    """
    v = dict(zip(labels, (float(x) for x in row)))
    n = sum(1 for k in labels if k.startswith('coupling_'))
    if n < 2 or any(k not in v for k in model_labels(n)):
        raise ValueError('array_model labels %r are not the model\'s (t_s, x_m ... '
                         'best_coupling_N)' % (tuple(labels),))
    now = np.array([v['coupling_%d' % (i + 1)] for i in range(n)])
    best = np.array([v['best_coupling_%d' % (i + 1)] for i in range(n)])
    with np.errstate(divide='ignore', invalid='ignore'):
        loss = 10.0 * np.log10(best / now)
        coupled = 10.0 * np.log10(now)
    j = int(np.argmin(now))
    align = align or {}
    return {
        'channels': n, 'measured': [i + 1 for i in measured(n)], 't_s': v['t_s'] - t0_s,
        'pose': {k: v[k] for k in POSE}, 'best_pose': {k: v['best_' + k] for k in POSE},
        'coupling': now.tolist(), 'coupling_db': coupled.tolist(),
        'loss_db': loss.tolist(), 'worst_channel': j + 1,
        'worst_channel_loss_db': float(loss[j]),
        'time_to_aligned_s': align.get('time_to_peak_s'),
        'samples': align.get('peak_samples'),
    }
