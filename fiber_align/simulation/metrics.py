# SPDX-License-Identifier: Apache-2.0
"""
Step and tracking metrics shared by ``simulate`` and ``analyze`` (pure numpy, SI units).

All times are in s, displacements in m. Every function takes plain arrays, so the same
code scores an offline simulation and a recorded bag.
"""

import math

import numpy as np

STEP_KEYS = ('settling_time_s', 'overshoot_pct', 'rise_time_s')
TRACK_KEYS = ('rms_error_m', 'max_error_m')


def step_metrics(t, y, r_final, y0=0.0, t0=None, band=0.02, floor_m=0.0):
    """
    Return step-response metrics of ``y(t)`` for a step from ``y0`` to ``r_final``.

    :param t: sample times (s), increasing.
    :param y: response (m), same length as ``t``.
    :param r_final: final value of the reference (m).
    :param y0: value before the step (m).
    :param t0: time of the step (s); default ``t[0]``.
    :param band: settling band as a fraction of the step size (0.02 = 2 %).
    :param floor_m: the band's least half-width (m): a band narrower than the measurement
        noise is left by noise alone, and the "settling time" is then the time of the
        last noise spike, not the loop's (:func:`loop_metrics` sets it from the noise).
    :returns: dict with ``settling_time_s`` (last time outside the band, measured from
        ``t0``; ``inf`` if still outside at the end), ``band_m`` (the band's half-width
        used, m), ``overshoot_pct`` (peak beyond the
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
    band_m = max(band * abs(step), float(floor_m))
    outside = (~ok) | (np.abs(z - 1.0) > band_m / abs(step))
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
        'band_m': band_m,
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


def find_steps(r, step_min_m):
    """
    Return the indices where the setpoint jumps by more than ``step_min_m`` (m).

    Index 0 counts as a step when ``|r[0]|`` exceeds ``step_min_m`` (a step from rest).
    """
    r = np.asarray(r, float)
    if r.size == 0:
        return np.zeros(0, int)
    jumps = np.nonzero(np.abs(np.diff(r)) > step_min_m)[0] + 1
    if abs(r[0]) > step_min_m and np.isfinite(r[0]):
        jumps = np.concatenate([[0], jumps])
    return jumps


def noise_rms(r, y):
    """
    Return the measurement noise's RMS (m) in ``y`` about ``r``, from sample to sample.

    The robust spread (MAD) of the first differences of ``y - r``, over sqrt(2): white
    sensor noise shows whole in them, the loop's slow motion and the few step jumps do
    not. 0.0 with fewer than 3 finite samples.
    """
    d = np.diff(np.asarray(y, float) - np.asarray(r, float))
    d = d[np.isfinite(d)]
    if d.size < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def step_settings(params):
    """
    Return :func:`loop_metrics`'s step keywords from the ``analyze`` settings (SI).

    ``params``: the ``analyze`` section of ``config/recorder.yaml`` (``step_min_m``,
    ``settling_band``, ``settling_noise_sigmas``); a key left out takes that file's value.
    """
    return {'step_min_m': float(params.get('step_min_m', 1e-6)),
            'band': float(params.get('settling_band', 0.02)),
            'noise_sigmas': float(params.get('settling_noise_sigmas', 5.0))}


def loop_metrics(t, r, y, v=None, v_limits=None, skip_s=0.0, step_min_m=1e-6, band=0.02,
                 max_steps=1000, noise_sigmas=5.0):
    """
    Return the closed-loop metrics of one run from per-period arrays (all SI).

    :param t: sample times (s); :param r: setpoint (m); :param y: displacement (m);
    :param v: drive voltage (V) or None; :param v_limits: (v_min, v_max) in V for the
        saturation figures; :param skip_s: leading time (s) left out of tracking;
    :param step_min_m: a setpoint jump larger than this (m) in one period is a step;
    :param band: settling band (fraction of the step); :param noise_sigmas: the band is
        at least this many times the run's measurement noise wide (:func:`noise_rms`;
        5: a sample of white noise leaves it with probability 6e-7).
    :returns: dict with ``noise_rms_m``, ``steps`` (list of per-step dicts from
        :func:`fiber_align.simulation.metrics.step_metrics` plus ``t_step_s``, ``from_m``,
        ``to_m``), ``tracking`` (:func:`~fiber_align.simulation.metrics.tracking_metrics`)
        and ``saturation`` (when ``v`` is given).
    """
    t = np.asarray(t, float)
    r = np.asarray(r, float)
    y = np.asarray(y, float)
    out = {'samples': int(t.size)}
    ok = np.isfinite(r)
    if ok.any() and t.size >= 2:
        # the samples that have a setpoint: a lockstep bag ends with the sample measured
        # after the last command, which nothing answered
        k0 = int(np.argmax(ok))
        k1 = r.size - int(np.argmax(ok[::-1]))
        if t[k1 - 1] - t[k0] > skip_s:
            out['tracking'] = tracking_metrics(t[k0:k1], r[k0:k1], y[k0:k1], skip_s)
        steps = []
        out['noise_rms_m'] = noise_rms(r[k0:k1], y[k0:k1])
        floor_m = float(noise_sigmas) * out['noise_rms_m']
        idx = find_steps(r, step_min_m)
        ends = np.concatenate([idx[1:], [r.size]]) if idx.size else idx
        for a, b in zip(idx[:max_steps].tolist(), ends[:max_steps].tolist()):
            if b - a < 2:
                continue
            seg = r[a:b]
            if np.nanmax(np.abs(seg - seg[0])) > step_min_m:
                continue   # the setpoint moves within the segment: not a held step
            y0 = float(r[a - 1]) if a > 0 and np.isfinite(r[a - 1]) else 0.0
            if seg[0] == y0:
                continue
            sm = step_metrics(t[a:b], y[a:b], float(seg[0]), y0=y0, t0=float(t[a]),
                              band=band, floor_m=floor_m)
            sm.update({'t_step_s': float(t[a]), 'from_m': y0, 'to_m': float(seg[0]),
                       'duration_s': float(t[b - 1] - t[a])})
            steps.append(sm)
        out['steps'] = steps
    if v is not None:
        out['saturation'] = saturation_metrics(t, np.asarray(v, float), v_limits)
    return out


def saturation_metrics(t, v, v_limits=None, tol_v=1e-6):
    """Return drive-voltage saturation figures: fraction and time at the limits (V, s)."""
    ok = np.isfinite(v)
    vv = v[ok]
    if vv.size == 0:
        return {'samples': 0}
    out = {'v_min_seen_v': float(vv.min()), 'v_max_seen_v': float(vv.max()),
           'samples': int(vv.size)}
    if v_limits is None:
        return out
    lo, hi = float(v_limits[0]), float(v_limits[1])
    sat = ok & ((v <= lo + tol_v) | (v >= hi - tol_v))
    out.update({'v_min_v': lo, 'v_max_v': hi,
                'at_limit_fraction': float(sat.sum()) / float(vv.size),
                'at_upper_samples': int((ok & (v >= hi - tol_v)).sum()),
                'at_lower_samples': int((ok & (v <= lo + tol_v)).sum())})
    if sat.any() and t.size > 1:
        s = sat.astype(np.int8)
        starts = np.nonzero(np.diff(np.concatenate([[0], s])) == 1)[0]
        stops = np.nonzero(np.diff(np.concatenate([s, [0]])) == -1)[0]
        dt = float(np.median(np.diff(t)))
        out['episodes'] = int(starts.size)
        out['longest_s'] = float(((stops - starts + 1).max()) * dt)
    else:
        out['episodes'] = 0
        out['longest_s'] = 0.0
    return out


def run_scores(loop):
    """
    Return the scores of one run from :func:`loop_metrics`'s result (the one scoring rule).

    ``settling_time_s``, ``overshoot_pct``, ``rise_time_s``: the worst over the setpoint
    steps (None without a step); ``rms_error_m``, ``max_error_m``: of the tracking
    window (None without one). ``fiber-align simulate``, ``bringup`` and the demo table
    all score a run with this.
    """
    steps = loop.get('steps') or []
    out = {}
    for k in STEP_KEYS:
        vals = [st[k] for st in steps if st.get(k) is not None]
        out[k] = max(vals) if vals else None
    tr = loop.get('tracking') or {}
    for k in TRACK_KEYS:
        out[k] = tr.get(k)
    return out
