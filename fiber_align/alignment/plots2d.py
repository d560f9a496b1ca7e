# SPDX-License-Identifier: Apache-2.0
"""
Plot a two-axis run for people: the path over the coupling map and the power over time.

The arrays are SI (s, m, W, from :func:`fiber_align.simulation.alignment2d_scenarios.run` with
``record=True``); only the axes are in um, dB, dBm and ms. Left: contours of the true loss
(dB) over x-y with the target where the sequencer first saw light, the sequencer's path
(coloured by state) and the hill climb's path; right: measured power (dBm) against time
for both, and the true loss (dB) below it.
"""

import numpy as np

from fiber_align.plant import optics as op
from fiber_align.plant import optics2d as o2

STATE_COLOURS = {
    'IDLE': '#999999', 'SEARCHING': '#e08a00', 'PEAKING': '#1f77b4',
    'TRACKING': '#2ca02c', 'RELEASING': '#9467bd', 'FAULT': '#d62728',
    'HELD': '#bcbd22',
}


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
    st = tr['state']
    seen = set()
    i0 = 0
    for i in range(1, len(st) + 1):
        if i == len(st) or st[i] != st[i0]:
            s = st[i0]
            ax.plot(x[i0:i + 1], y[i0:i + 1], style, lw=1.0, zorder=3,
                    color=STATE_COLOURS.get(s, 'k'),
                    label=None if s in seen else '%s: %s' % (label, s))
            seen.add(s)
            i0 = i


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
