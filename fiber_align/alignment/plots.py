# SPDX-License-Identifier: Apache-2.0
"""
Plot an alignment run for people: optical power (dBm) and displacement (um) over time.

The arrays are SI (s, m, W, from :func:`fiber_align.simulation.alignment_scenarios.run` with
``record=True``); only the axes are in dBm, um and ms for reading. The background is
shaded by sequencer state (search, peak, track, ...).
"""

import numpy as np

STATE_COLOURS = {
    'IDLE': '#eeeeee', 'SEARCHING': '#fde2b8', 'PEAKING': '#c9e4ff',
    'TRACKING': '#d4f4d2', 'RELEASING': '#e6d9f7', 'FAULT': '#f9c0c0',
    'HELD': '#fff3a8',
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
