# SPDX-License-Identifier: Apache-2.0
"""
Align recorded streams to control periods, compute the run's metrics, write reports.

Alignment (see docs/analysis.md): the time base is the ``displacement`` stream, one
sample per control period, time = header stamp relative to the first sample (s).
``std_msgs/Float64`` streams carry no stamp, so:

* lockstep bags (the bag holds ``/clock`` messages): the i-th message of every Float64
  stream belongs to the i-th displacement sample (the graph publishes exactly one per
  period); bag timestamps are wall time and are used only for latency;
* real-time bags: a message belongs to the period in which it was received, i.e. the
  value for sample i is the last message received before sample i+1 was received
  (zero-order hold; NaN before the first message).

The metrics are computed by :func:`fiber_align.simulation.metrics.loop_metrics` from plain
arrays, so an offline simulation and a bag of the same run give the same numbers.
"""

import html
import json
import math
from pathlib import Path

import numpy as np

from fiber_align.config import load_params
from fiber_align.jsonout import json_clean, json_default

FLOAT_STREAMS = ('setpoint', 'feedforward_voltage', 'feedback_voltage', 'drive_voltage',
                 'optical_power')


def default_params():
    """Return the analysis defaults from ``config/recorder.yaml`` (node ``analyze``)."""
    return load_params('recorder.yaml', 'analyze')


def align_index(disp_t_ns, stream_t_ns):
    """
    Return, for each displacement sample, the index of its message in a real-time stream.

    The message of sample i is the last one received before sample i+1 was received
    (any time after the last sample for the last one); -1 where there is none.

    :param disp_t_ns: receive times of the displacement samples (ns, sorted).
    :param stream_t_ns: receive times of the stream (ns, sorted).
    """
    edges = np.empty_like(disp_t_ns)
    edges[:-1] = disp_t_ns[1:]
    edges[-1:] = np.iinfo(np.int64).max
    return np.searchsorted(stream_t_ns, edges, side='left') - 1


def align_values(n, values, idx=None):
    """Return ``n`` per-sample values: by order (``idx`` None) or gathered at ``idx``."""
    if idx is None:
        if values.shape[0] >= n:
            return values[:n]
        out = np.full(n, np.nan)
        out[:values.shape[0]] = values
        return out
    out = values[np.maximum(idx, 0)]
    out[idx < 0] = np.nan
    return out


def align_to_samples(streams, lockstep):
    """
    Return per-control-period arrays from decoded streams (see the module docstring).

    :param streams: mapping of stream key -> :class:`fiber_align.analysis.bag.Stream`;
        needs ``displacement``.
    :param lockstep: True to align Float64 streams by message order.
    :returns: dict with ``t`` (s), ``y`` (m), ``stamp_ns``, ``recv_ns`` (displacement
        receive times), one array per Float64 stream present (SI, NaN where missing)
        and ``method`` (``order`` or ``receive-time``).
    """
    d = streams['displacement']
    stamp = d.fields['stamp_ns']
    out = {'t': (stamp - stamp[0]) / 1e9 if stamp.size else np.zeros(0),
           'y': d.fields['position'], 'stamp_ns': stamp, 'recv_ns': d.t_ns,
           'method': 'order' if lockstep else 'receive-time'}
    n = stamp.shape[0]
    for key in FLOAT_STREAMS:
        s = streams.get(key)
        if s is None:
            continue
        idx = None if lockstep else align_index(d.t_ns, s.t_ns)
        out[key] = align_values(n, s.fields['data'], idx)
    return out


def _stats(x):
    """Return mean, std, p50, p99, max of ``x`` (same unit as ``x``)."""
    x = x[np.isfinite(x)]
    if x.size == 0:
        return None
    return {'mean': float(x.mean()), 'std': float(x.std()), 'p50': float(np.median(x)),
            'p99': float(np.percentile(x, 99)), 'max': float(x.max()), 'n': int(x.size)}


def timing_metrics(al, drive_t_ns=None, lockstep=False):
    """
    Return loop timing: period and jitter (s) from stamps and receive times, latency.

    Latency is the time from receiving a displacement sample to receiving the drive
    command of the same period (paired by order in lockstep, by receive time otherwise).
    """
    out = {}
    stamp = al['stamp_ns']
    if stamp.size > 2:
        p = np.diff(stamp) / 1e9
        out['period_s'] = _stats(p)
        out['period_jitter_s'] = float(p.std())
        rp = np.diff(al['recv_ns']) / 1e9
        out['receive_period_s'] = _stats(rp)
        out['receive_jitter_s'] = float(rp.std())
    if drive_t_ns is not None and al['recv_ns'].size:
        rv = al['recv_ns']
        if lockstep:
            m = min(rv.size, drive_t_ns.size)
            lat = (drive_t_ns[:m] - rv[:m]) / 1e9
        else:
            j = np.searchsorted(drive_t_ns, rv, side='left')
            edges = np.concatenate([rv[1:], [np.iinfo(np.int64).max]])
            okj = j < drive_t_ns.size
            jj = np.minimum(j, drive_t_ns.size - 1)
            okj &= drive_t_ns[jj] < edges
            lat = (drive_t_ns[jj[okj]] - rv[okj]) / 1e9
        out['sensor_to_command_latency_s'] = _stats(lat)
    return out


def optical_metrics(t, p, light_threshold_w, t0=0.0):
    """
    Return alignment events from optical power ``p`` (W) at times ``t`` (s).

    ``time_to_first_light_s``: first time ``p >= light_threshold_w``;
    ``time_to_peak_s``: first time ``p`` reaches 99 % of its maximum;
    ``losses``: drops below the threshold after first light, with ``dark_time_s``;
    ``final_vs_peak_db``: last power against the peak (dB).
    """
    ok = np.isfinite(p)
    if not ok.any():
        return {'samples': 0}
    pk = float(np.max(p[ok]))
    out = {'peak_w': pk, 'final_w': float(p[ok][-1]), 'threshold_w': float(light_threshold_w)}
    lit = ok & (p >= light_threshold_w)
    if lit.any():
        i = int(np.argmax(lit))
        out['time_to_first_light_s'] = float(t[i] - t0)
        after = lit[i:]
        drops = np.nonzero(np.diff(after.astype(np.int8)) == -1)[0]
        out['losses'] = int(drops.size)
        dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
        out['dark_time_s'] = float((~after).sum() * dt)
    else:
        out['time_to_first_light_s'] = None
        out['losses'] = 0
    ip = int(np.argmax(ok & (p >= 0.99 * pk))) if pk > 0 else int(np.argmax(np.where(ok, p, -1)))
    out['time_to_peak_s'] = float(t[ip] - t0)
    if pk > 0 and out['final_w'] > 0:
        out['final_vs_peak_db'] = float(10 * math.log10(out['final_w'] / pk))
    return out


def hysteresis_metrics(u, y, bins=50):
    """Return the voltage-displacement loop figures: ranges and maximum loop width (V, m)."""
    ok = np.isfinite(u) & np.isfinite(y)
    u, y = u[ok], y[ok]
    if u.size < 4:
        return {'samples': int(u.size)}
    du = np.diff(u)
    uu, yy = u[1:], y[1:]
    lo, hi = float(u.min()), float(u.max())
    out = {'u_min_v': lo, 'u_max_v': hi, 'y_min_m': float(y.min()), 'y_max_m': float(y.max()),
           'samples': int(u.size)}
    if hi <= lo:
        return out
    edges = np.linspace(lo, hi, bins + 1)
    b = np.clip(np.searchsorted(edges, uu, side='right') - 1, 0, bins - 1)

    def mean_by_bin(sel):
        s = np.bincount(b[sel], yy[sel], bins)
        c = np.bincount(b[sel], None, bins)
        with np.errstate(invalid='ignore', divide='ignore'):
            return s / c
    up, down = mean_by_bin(du > 0), mean_by_bin(du < 0)
    w = np.abs(down - up)
    if np.isfinite(w).any():
        k = int(np.nanargmax(w))
        out['max_loop_width_m'] = float(w[k])
        out['max_width_at_v'] = float(0.5 * (edges[k] + edges[k + 1]))
        span = out['y_max_m'] - out['y_min_m']
        out['loop_width_pct'] = float(100 * w[k] / span) if span > 0 else None
    return out


# --------------------------------------------------------------------------- report text

def _fmt(v, scale=1.0, unit='', nd=4):
    if v is None:
        return 'n/a'
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return ('%.*g %s' % (nd, v * scale, unit)).strip()


def _db(v):
    return 'n/a' if v is None else '%.4f dB' % v


def _dbm(w):
    return _fmt(10 * math.log10(w / 1e-3) if w and w > 0 else None, 1, 'dBm')


def align_rows(al):
    """Return the alignment table: (section, name, value) rows of ``metrics.align``."""
    state = al.get('state') or 'n/a'
    if al.get('fault_reason'):
        state += ' (%s)' % al['fault_reason']
    rows = [('alignment', 'final state', state),
            ('alignment', 'time to first light',
             _fmt(al.get('time_to_first_light_s'), 1e3, 'ms')),
            ('alignment', 'time to peak', _fmt(al.get('time_to_peak_s'), 1e3, 'ms')),
            ('alignment', 'peak samples', 'n/a' if al.get('peak_samples') is None
             else str(al['peak_samples'])),
            ('alignment', 'final loss', _db(al.get('final_loss_db'))),
            ('alignment', 'switch cycles', str(al.get('switch_cycles', 0)))]
    if al.get('cycles'):
        rows += [('alignment', 'switch cycle loss (max)', _db(al.get('cycle_loss_max_db'))),
                 ('alignment', 'switch rise time (max)',
                  _fmt(al.get('switch_rise_time_max_s'), 1e3, 'ms'))]
    rows += [('alignment', 'tracking loss (max)', _db(al.get('tracking_max_loss_db'))),
             ('alignment', 'loss reference', '%s (highest mean power over %s)'
              % (_dbm(al.get('reference_power_w')),
                 _fmt(al.get('reference_window_s'), 1e3, 'ms')))]
    return rows


def array_rows(m):
    """Return the report's (section, name, value) rows of ``metrics.array``."""
    p, b = m['pose'], m['best_pose']
    rows = [
        ('array', 'channels', '%d (measured: %d and %d)' % (m['channels'], *m['measured'])),
        ('array', 'roll found', '%s (best joint pose %s, off by %s)' % (
            _fmt(p['roll_rad'], 1e3, 'mrad'), _fmt(b['roll_rad'], 1e3, 'mrad'),
            _fmt(p['roll_rad'] - b['roll_rad'], 1e3, 'mrad', 2))),
        ('array', 'x, y found', '%s, %s (best %s, %s)' % tuple(
            _fmt(v, 1e6, 'um') for v in (p['x_m'], p['y_m'], b['x_m'], b['y_m']))),
        ('array', 'worst channel', 'channel %d: %.4f dB below its coupling at the best '
         'joint pose' % (m['worst_channel'], m['worst_channel_loss_db'])),
        ('array', 'time to aligned', _fmt(m['time_to_aligned_s'], 1e3, 'ms')),
        ('array', 'samples', 'n/a' if m['samples'] is None else str(m['samples'])),
        ('array', 'at', 'the model\'s last message, %s into the run' % _fmt(
            m['t_s'], 1.0, 's'))]
    for i, (c, loss) in enumerate(zip(m['coupling_db'], m['loss_db'])):
        name = 'channel %d%s' % (i + 1, ' (measured)' if i + 1 in m['measured'] else '')
        rows.append(('array channels', name, '%.3f dB coupled, %.4f dB against the best '
                     'joint pose' % (c, loss)))
    return rows


def metrics_rows(res):
    """
    Return (section, name, value for people) rows of a metrics result (um, V, ms, dB).

    An alignment run (``kind`` ``alignment``) starts with its alignment table and has no
    step or tracking rows; a tracking run starts with its tracking and step rows.
    """
    rows = []
    m = res.get('metrics', {})
    aligning = res.get('kind') == 'alignment'
    if aligning:
        rows += align_rows(m.get('align') or {})
    if m.get('array'):
        rows += array_rows(m['array'])
    tr = m.get('loop', {}).get('tracking')
    if tr:
        rows += [('tracking', 'RMS error', _fmt(tr['rms_error_m'], 1e6, 'um')),
                 ('tracking', 'max error', _fmt(tr['max_error_m'], 1e6, 'um'))]
    if m.get('loop', {}).get('noise_rms_m') is not None:
        rows.append(('tracking', 'measurement noise (RMS, sample to sample)',
                     _fmt(m['loop']['noise_rms_m'], 1e9, 'nm')))
    for i, s in enumerate(m.get('loop', {}).get('steps', [])[:20]):
        name = 'step %d (%.4g -> %.4g um at %.6g ms)' % (
            i + 1, s['from_m'] * 1e6, s['to_m'] * 1e6, s['t_step_s'] * 1e3)
        rows += [(name, 'rise time', _fmt(s['rise_time_s'], 1e3, 'ms')),
                 (name, 'settling time' + (' (band +-%.3g nm)' % (s['band_m'] * 1e9)
                                           if 'band_m' in s else ''),
                  _fmt(s['settling_time_s'], 1e3, 'ms')),
                 (name, 'overshoot', _fmt(s['overshoot_pct'], 1, '%'))]
    sat = m.get('loop', {}).get('saturation')
    if sat and 'at_limit_fraction' in sat:
        rows += [('drive', 'at limit', _fmt(sat['at_limit_fraction'], 100, '%')),
                 ('drive', 'limits', '%g .. %g V' % (sat['v_min_v'], sat['v_max_v'])),
                 ('drive', 'longest at limit', _fmt(sat['longest_s'], 1e3, 'ms'))]
    elif sat and 'v_max_seen_v' in sat:
        rows += [('drive', 'range', '%.4g .. %.4g V' % (sat['v_min_seen_v'],
                                                        sat['v_max_seen_v']))]
    tm = m.get('timing', {})
    if tm.get('period_s'):
        rows += [('timing', 'period (stamps)', _fmt(tm['period_s']['mean'], 1e3, 'ms')),
                 ('timing', 'period jitter (stamps, std)',
                  _fmt(tm['period_jitter_s'], 1e3, 'ms')),
                 ('timing', 'receive jitter (std)', _fmt(tm['receive_jitter_s'], 1e3, 'ms'))]
    lat = tm.get('sensor_to_command_latency_s')
    if lat:
        rows += [('timing', 'sensor-to-command latency p50',
                  _fmt(lat['p50'], 1e3, 'ms')),
                 ('timing', 'sensor-to-command latency p99', _fmt(lat['p99'], 1e3, 'ms'))]
    op = m.get('optical')
    if op and 'peak_w' in op:
        if not aligning:   # the alignment table has the run's own first light and peak
            rows += [('optical', 'time to first light',
                      _fmt(op.get('time_to_first_light_s'), 1e3, 'ms')),
                     ('optical', 'time to peak', _fmt(op.get('time_to_peak_s'), 1e3, 'ms'))]
        rows += [('optical', 'peak power', _dbm(op['peak_w'])),
                 ('optical', 'losses of light after first light', str(op.get('losses', 0)))]
    hy = m.get('hysteresis')
    if hy and 'max_loop_width_m' in hy:
        rows += [('hysteresis', 'max loop width', _fmt(hy['max_loop_width_m'], 1e6, 'um')),
                 ('hysteresis', 'at', _fmt(hy['max_width_at_v'], 1, 'V')),
                 ('hysteresis', 'width / range', _fmt(hy.get('loop_width_pct'), 1, '%'))]
    return rows


def to_text(res):
    """Return a plain-text summary of an analysis result."""
    lines = ['bag: %s (%s run, %s, aligned by %s)' % (
        res['bag'], res.get('kind', 'unknown'), 'lockstep' if res['lockstep'] else 'real time',
        res.get('alignment', 'n/a'))]
    for note in res.get('notes', []):
        lines.append('note: ' + note)
    for sec, name, val in metrics_rows(res):
        lines.append('%-28s %-34s %s' % (sec[:28], name, val))
    return '\n'.join(lines)


def write_report(path, res, figures):
    """
    Write a Markdown (``.md``) or HTML (``.html``/``.htm``) report; return its path.

    :param figures: list of (title, path) of the figures; linked relative to the report.
    """
    path = Path(path)
    rows = metrics_rows(res)
    rel = []
    for title, f in figures:
        try:
            rel.append((title, str(Path(f).resolve().relative_to(path.resolve().parent))))
        except ValueError:
            rel.append((title, str(Path(f).resolve())))
    if path.suffix.lower() in ('.html', '.htm'):
        e = html.escape
        parts = ['<!DOCTYPE html><html><head><meta charset="utf-8"><title>fiber_align run '
                 'report</title></head><body>', '<h1>Run report</h1>',
                 '<p>Bag: <code>%s</code> (%s run, %s, streams aligned by %s)</p>'
                 % (e(str(res['bag'])), e(res.get('kind', 'unknown')),
                    'lockstep' if res['lockstep'] else 'real time',
                    e(res.get('alignment', 'n/a')))]
        for note in res.get('notes', []):
            parts.append('<p><b>Note:</b> %s</p>' % e(note))
        parts.append('<table border="1" cellpadding="4"><tr><th>section</th><th>metric</th>'
                     '<th>value</th></tr>')
        parts += ['<tr><td>%s</td><td>%s</td><td>%s</td></tr>' % (e(a), e(b), e(c))
                  for a, b, c in rows]
        parts.append('</table>')
        for title, f in rel:
            parts.append('<h2>%s</h2><img src="%s" alt="%s" style="max-width:100%%">'
                         % (e(title), e(f), e(title)))
        parts.append('<details><summary>metrics (JSON, SI units)</summary><pre>%s</pre>'
                     '</details></body></html>' % e(json.dumps(res['metrics'], indent=1,
                                                               default=json_default)))
        text = '\n'.join(parts)
    else:
        parts = ['# Run report', '',
                 'Bag: `%s` (%s run, %s, streams aligned by %s)' % (
                     res['bag'], res.get('kind', 'unknown'),
                     'lockstep' if res['lockstep'] else 'real time',
                     res.get('alignment', 'n/a')), '']
        parts += ['> Note: %s' % n for n in res.get('notes', [])]
        parts += ['', '| section | metric | value |', '|---|---|---|']
        parts += ['| %s | %s | %s |' % r for r in rows]
        for title, f in rel:
            parts += ['', '## %s' % title, '', '![%s](%s)' % (title, f)]
        text = '\n'.join(parts) + '\n'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding='utf-8')
    return path


def to_json(res):
    """Return the analysis result as JSON text (SI units; inf/nan as strings)."""
    return json.dumps(json_clean(res, nonfinite_as_text=True), indent=2, default=json_default)
