# SPDX-License-Identifier: Apache-2.0
"""
Figures of an offline alignment run for people: the one-axis and the two-axis machine.

The arrays are SI (s, m, W, from ``run(..., record=True)`` of
:mod:`fiber_align.simulation.alignment_scenarios` and
:mod:`fiber_align.simulation.alignment2d_scenarios`); only the axes are in um, dB, dBm and
ms for reading.

:func:`plot_run` (one axis): optical power (dBm) and displacement (um) over time, the
background shaded by sequencer state (search, peak, track, ...).

:func:`plot_run2d` (two axes): left, contours of the true loss (dB) over x-y with the
target where the sequencer first saw light, the sequencer's path (coloured by state) and
the hill climb's path; right, measured power (dBm) against time for both, and the true
loss (dB) below it.
"""

import numpy as np

from fiber_align.plant import optics as op
from fiber_align.plant import optics2d as o2

#: the background of each state in the one-axis figure
STATE_COLOURS = {
    'IDLE': '#eeeeee', 'SEARCHING': '#fde2b8', 'PEAKING': '#c9e4ff',
    'TRACKING': '#d4f4d2', 'RELEASING': '#e6d9f7', 'FAULT': '#f9c0c0',
    'HELD': '#fff3a8',
}
#: the path's colour in each state in the two-axis figure
PATH_COLOURS = {
    'IDLE': '#999999', 'SEARCHING': '#e08a00', 'PEAKING': '#1f77b4',
    'TRACKING': '#2ca02c', 'RELEASING': '#9467bd', 'FAULT': '#d62728',
    'HELD': '#bcbd22',
}


def _segments(state):
    """Yield ``(i0, i1, state)`` runs of equal state (indices, end exclusive)."""
    if len(state) == 0:
        return
    i0 = 0
    for i in range(1, len(state) + 1):
        if i == len(state) or state[i] != state[i0]:
            yield i0, i, state[i0]
            i0 = i


def plot_run(res, path, title=None):
    """
    Write a two-panel figure of a recorded run to ``path`` (PNG, SVG or PDF).

    :param res: the dict of ``run(..., record=True)`` (needs ``trace``).
    :param path: output file.
    :param title: figure title; default names the scenario and the outcome.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    tr = res['trace']
    t = tr['t']
    use_ms = t[-1] < 2.0 if t.size else True
    ts = t * (1e3 if use_ms else 1.0)
    p_dbm = 10.0 * np.log10(np.maximum(tr['p'], 1e-15) / 1e-3)
    pt_dbm = 10.0 * np.log10(np.maximum(tr['p_true'], 1e-15) / 1e-3)
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(10, 6.5))
    for ax in (ax1, ax2):
        seen = set()
        for i0, i1, st in _segments(tr['state']):
            a = ts[i0]
            b = ts[i1] if i1 < len(ts) else ts[-1]
            ax.axvspan(a, b, color=STATE_COLOURS.get(st, '#ffffff'), lw=0,
                       label=st if (ax is ax1 and st not in seen) else None)
            seen.add(st)
    ax1.plot(ts, p_dbm, lw=0.8, color='C0', label='measured power')
    ax1.plot(ts, pt_dbm, lw=0.8, color='C3', ls='--', label='true coupled power')
    pmax = np.nanmax(tr['p_max']) if tr['p_max'].size else 0.0
    if pmax > 0:
        ax1.axhline(10.0 * np.log10(pmax / 1e-3), color='k', lw=0.6, ls=':',
                    label='true maximum')
    ax1.set_ylabel('optical power (dBm)')
    ax1.set_ylim(max(-85.0, np.nanmin(p_dbm) - 3.0), 5.0)
    ax1.legend(loc='lower right', fontsize=7, ncol=3)
    ax1.grid(alpha=0.3)
    ax2.plot(ts, tr['r'] * 1e6, lw=0.8, color='C1', label='setpoint')
    ax2.plot(ts, tr['y'] * 1e6, lw=0.8, color='C0', label='measured displacement')
    ax2.plot(ts, tr['slot'] * 1e6, lw=1.0, color='k', ls=':', label='slot (true, unknown)')
    ax2.set_ylabel('displacement (um)')
    ax2.set_xlabel('time (%s)' % ('ms' if use_ms else 's'))
    ax2.legend(loc='lower right', fontsize=7)
    ax2.grid(alpha=0.3)
    if title is None:
        parts = ['scenario %s, seed %s' % (res.get('scenario'), res.get('seed'))]
        if res.get('final_loss_db') is not None:
            parts.append('aligned %.3f dB below max' % res['final_loss_db'])
        if res.get('time_to_peak_s') is not None:
            parts.append('in %.0f ms' % (res['time_to_peak_s'] * 1e3))
        if res.get('end_state') == 'FAULT':
            parts.append('FAULT: %s' % res.get('end_fault_reason'))
        title = ', '.join(parts)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _loss_map(res, tr, xs, ys):
    """Return the true loss (dB) on the grid for the target at the first reading."""
    oparams = None
    link = o2.OpticalLink2D.from_params(oparams, None, seed=0,
                                        position_x_m=tr['tx'][0], position_y_m=tr['ty'][0])
    gx, gy = np.meshgrid(xs, ys)
    return gx, gy, link.coupling.loss_db(0.0, gx, gy)


def _path(ax, tr, label, coloured, style):
    """Draw one method's tip path (um), by state if ``coloured``."""
    x, y = tr['x'] * 1e6, tr['y'] * 1e6
    if not coloured:
        ax.plot(x, y, style, lw=0.8, color='k', alpha=0.7, label=label)
        ax.plot(x[-1], y[-1], 'ks', ms=4)
        return
    seen = set()
    for i0, i1, s in _segments(tr['state']):
        ax.plot(x[i0:i1 + 1], y[i0:i1 + 1], style, lw=1.0, zorder=3,
                color=PATH_COLOURS.get(s, 'k'),
                label=None if s in seen else '%s: %s' % (label, s))
        seen.add(s)


def plot_run2d(res, path, title=None):
    """
    Write the figure of a recorded 2-D run to ``path`` (PNG, SVG or PDF); return ``path``.

    :param res: the dict of ``alignment2d_scenarios.run(..., record=True)`` (``trace`` in it and in
        ``res['baseline']``).
    :param path: output file.
    :param title: figure title; default names the scenario and both outcomes.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    tr = res['trace']
    base = res.get('baseline', {}).get('trace')
    fig = plt.figure(figsize=(13, 6))
    ax = fig.add_subplot(1, 2, 1)
    xs = np.linspace(-2e-6, 67e-6, 140)
    gx, gy, loss = _loss_map(res, tr, xs, xs)
    levels = [0.05, 0.5, 3, 10, 20, 40, 64]
    cs = ax.contour(gx * 1e6, gy * 1e6, loss, levels=levels, cmap='viridis_r', linewidths=0.8)
    ax.clabel(cs, fmt='%g dB', fontsize=7)
    _path(ax, tr, 'sequencer', True, '-')
    if base is not None:
        _path(ax, base, 'hill climb', False, '--')
    ax.plot(tr['tx'] * 1e6, tr['ty'] * 1e6, 'r-', lw=3, alpha=0.35, zorder=1,
            label='target path')
    ax.plot(tr['tx'][0] * 1e6, tr['ty'][0] * 1e6, 'r+', ms=12, mew=2,
            label='target (true, unknown)')
    ax.add_patch(plt.Rectangle((0, 0), 65, 65, fill=False, ls=':', color='gray'))
    ax.set_xlim(-3, 68)
    ax.set_ylim(-3, 68)
    ax.set_aspect('equal')
    ax.set_xlabel('x (um)')
    ax.set_ylabel('y (um)')
    ax.set_title('tip path over the coupling loss map (contours in dB)', fontsize=9)
    ax.legend(loc='upper left', fontsize=6, ncol=2)
    a1 = fig.add_subplot(2, 2, 2)
    a2 = fig.add_subplot(2, 2, 4, sharex=a1)
    t_end = tr['t'][-1] if tr['t'].size else 0.0
    ms = t_end < 2.0
    sc = 1e3 if ms else 1.0
    for trace, label, colour in ((tr, 'sequencer', 'C0'), (base, 'hill climb', 'C1')):
        if trace is None:
            continue
        t, p_dbm, loss = trace['t'], op.w_to_dbm(trace['p']), trace['loss_db']
        note = ''
        if not ms and t.size > 2000:
            # seconds of samples would fill the panel: draw the worst of each 100 ms
            n = int(round(0.1 / max(t[1] - t[0], 1e-9)))
            m = t.size // n
            t = t[:m * n:n]
            p_dbm = p_dbm[:m * n].reshape(m, n).min(axis=1)
            loss = loss[:m * n].reshape(m, n).max(axis=1)
            note = ', worst per 100 ms'
        a1.plot(t * sc, p_dbm, lw=0.7, color=colour, label='%s, measured%s' % (label, note))
        a2.plot(t * sc, np.maximum(loss, 1e-4), lw=0.8, color=colour, label=label + note)
    a1.set_ylabel('optical power (dBm)')
    a1.set_ylim(-80, 5)
    a1.grid(alpha=0.3)
    a1.legend(fontsize=7, loc='lower right')
    a2.set_yscale('log')
    a2.set_ylim(1e-3, 100)
    a2.axhline(0.05, color='k', ls=':', lw=0.8)
    a2.set_ylabel('true loss (dB)')
    a2.set_xlabel('time (%s)' % ('ms' if ms else 's'))
    a2.grid(alpha=0.3, which='both')
    a2.legend(fontsize=7, loc='upper right')
    if title is None:
        def one(r, name):
            if r.get('time_to_peak_s') is None:
                return '%s: %s %s' % (name, r.get('end_state'), r.get('end_fault_reason'))
            return '%s: %.3f dB in %.0f ms, %d peak samples' % (
                name, r['final_loss_db'], r['time_to_peak_s'] * 1e3, r['peak_samples'])
        title = 'scenario %s, seed %s | %s | %s' % (
            res.get('scenario'), res.get('seed'), one(res, 'sequencer'),
            one(res.get('baseline', {}), 'hill climb'))
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
