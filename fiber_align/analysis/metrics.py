# SPDX-License-Identifier: Apache-2.0
"""
Step and tracking metrics shared by ``simulate`` and ``analyze`` (pure numpy, SI units).

All times are in s, displacements in m. Every function takes plain arrays, so the same
code scores an offline simulation and a recorded bag.
"""

import math

import numpy as np


def step_metrics(t, y, r_final, y0=0.0, t0=None, band=0.02):
    """
    Return step-response metrics of ``y(t)`` for a step from ``y0`` to ``r_final``.

    :param t: sample times (s), increasing.
    :param y: response (m), same length as ``t``.
    :param r_final: final value of the reference (m).
    :param y0: value before the step (m).
    :param t0: time of the step (s); default ``t[0]``.
    :param band: settling band as a fraction of the step size (0.02 = 2 %).
    :returns: dict with ``settling_time_s`` (last time outside the band, measured from
        ``t0``; ``inf`` if still outside at the end), ``overshoot_pct`` (peak beyond the
        final value in % of the step, >= 0), ``rise_time_s`` (10 % to 90 % of the step;
        ``inf`` if never reached), ``steady_state_error_m`` (mean over the last 5 % of
        the samples) and ``peak_m``.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.shape != y.shape or t.size < 2:
        raise ValueError('t and y must be 1-D arrays of the same length >= 2')
    t0 = float(t[0]) if t0 is None else float(t0)
    step = float(r_final) - float(y0)
    if step == 0.0:
        raise ValueError('step size is zero')
    sel = t >= t0
    ts, ys = t[sel], y[sel]
    # normalised response: 0 before, 1 at the target
    z = (ys - y0) / step
    ok = np.isfinite(z)
    outside = (~ok) | (np.abs(z - 1.0) > band)
    if outside[-1]:
        settling = math.inf
    elif not outside.any():
        settling = 0.0
    else:
        last = int(np.nonzero(outside)[0][-1])
        settling = float(ts[last + 1] - t0)
    zf = np.where(ok, z, -np.inf)
    peak = float(np.max(zf))
    overshoot = max(0.0, (peak - 1.0) * 100.0)
    i10 = np.nonzero(zf >= 0.1)[0]
    i90 = np.nonzero(zf >= 0.9)[0]
    if i10.size and i90.size:
        rise = float(ts[i90[0]] - ts[i10[0]])
    else:
        rise = math.inf
    tail = ys[-max(1, ys.size // 20):]
    return {
        'settling_time_s': settling,
        'overshoot_pct': overshoot,
        'rise_time_s': rise,
        'steady_state_error_m': float(np.nanmean(tail) - r_final),
        'peak_m': float(y0 + peak * step),
    }


def tracking_metrics(t, r, y, skip_s=0.0):
    """
    Return tracking-error metrics of ``y`` against ``r`` after ``skip_s``.

    :param t: sample times (s).
    :param r: reference (m).
    :param y: response (m).
    :param skip_s: leading time (s) left out, e.g. the first period of a periodic
        reference.
    :returns: dict with ``rms_error_m``, ``max_error_m`` (absolute) and ``mean_error_m``;
        NaN samples of ``y`` count as errors of infinite size (``max_error_m`` = inf).
    """
    t = np.asarray(t, dtype=float)
    r = np.asarray(r, dtype=float)
    y = np.asarray(y, dtype=float)
    if not (t.shape == r.shape == y.shape):
        raise ValueError('t, r and y must have the same shape')
    sel = t >= t[0] + skip_s
    if not sel.any():
        raise ValueError('skip_s=%g leaves no samples (run is %g s)'
                         % (skip_s, t[-1] - t[0]))
    e = y[sel] - r[sel]
    if not np.all(np.isfinite(e)):
        return {'rms_error_m': math.inf, 'max_error_m': math.inf, 'mean_error_m': math.nan}
    return {
        'rms_error_m': float(np.sqrt(np.mean(e * e))),
        'max_error_m': float(np.max(np.abs(e))),
        'mean_error_m': float(np.mean(e)),
    }
