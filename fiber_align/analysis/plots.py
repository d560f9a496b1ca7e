# SPDX-License-Identifier: Apache-2.0
"""
Figures of a recorded run: signals against time, error, hysteresis loop, gains, power.

Inputs are SI arrays (s, m, V, W); the axes are for people: ms, um, V, dBm. Long runs are
decimated to a min/max envelope of at most ``max_points`` points per line, so an hour at
1 kHz plots as fast as a second and still shows every excursion.
"""

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def envelope(t, y, max_points=4000):
    """Return (t, y) decimated to a min/max envelope of about ``max_points`` points."""
    t = np.asarray(t)
    y = np.asarray(y, float)
    n = y.shape[0]
    if n <= max_points:
        return t, y
    nb = max(1, max_points // 2)
    k = n // nb
    m = k * nb
    yb = y[:m].reshape(nb, k)
    with np.errstate(all='ignore'):
        lo = np.nanargmin(np.where(np.isnan(yb), np.inf, yb), axis=1)
        hi = np.nanargmax(np.where(np.isnan(yb), -np.inf, yb), axis=1)
    base = np.arange(nb) * k
    idx = np.sort(np.concatenate([base + lo, base + hi]))
    return t[idx], y[idx]


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def plot_time(path, t, y, r=None, volts=None, max_points=4000):
    """Plot setpoint and displacement (um) and the voltages (V) against time (ms)."""
    plt = _plt()
    fig, axes = plt.subplots(2 if volts else 1, 1, sharex=True, figsize=(9, 6 if volts else 3.5),
                             squeeze=False)
    ax = axes[0, 0]
    if r is not None:
        ax.plot(*_um(t, r, max_points), label='setpoint', lw=1.0)
    ax.plot(*_um(t, y, max_points), label='displacement', lw=1.0)
    ax.set_ylabel('displacement (um)')
    ax.legend(loc='best')
    ax.grid(True, alpha=0.3)
    if volts:
        ax2 = axes[1, 0]
        for name, v in volts.items():
            tt, vv = envelope(t, v, max_points)
            ax2.plot(tt * 1e3, vv, label=name, lw=1.0)
        ax2.set_ylabel('voltage (V)')
        ax2.legend(loc='best')
        ax2.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel('time (ms)')
    return _save(fig, path)


def _um(t, y, max_points):
    tt, yy = envelope(t, y, max_points)
    return tt * 1e3, yy * 1e6


def plot_error(path, t, r, y, max_points=4000):
    """Plot the tracking error y - r (um) against time (ms)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(*_um(t, np.asarray(y) - np.asarray(r), max_points), lw=1.0,
            label='error (displacement - setpoint)')
    ax.set_xlabel('time (ms)')
    ax.set_ylabel('error (um)')
    ax.legend(loc='best')
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def plot_loop(path, u, y, max_points=20000):
    """Plot displacement (um) against drive voltage (V): the hysteresis loop."""
    plt = _plt()
    u = np.asarray(u)
    y = np.asarray(y)
    step = max(1, u.shape[0] // max_points)
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(u[::step], y[::step] * 1e6, lw=0.8, label='measured')
    ax.set_xlabel('drive voltage (V)')
    ax.set_ylabel('displacement (um)')
    ax.legend(loc='best')
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def plot_gains(path, t, gains, max_points=4000):
    """Plot the fuzzy PID gains (name -> array) against time (ms), one panel per gain."""
    plt = _plt()
    fig, axes = plt.subplots(len(gains), 1, sharex=True, figsize=(9, 2.2 * len(gains)),
                             squeeze=False)
    for ax, (name, g) in zip(axes[:, 0], gains.items()):
        tt, gg = envelope(t, g, max_points)
        ax.plot(tt * 1e3, gg, lw=1.0, label=name)
        ax.set_ylabel(name)
        ax.legend(loc='best')
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel('time (ms)')
    return _save(fig, path)


def plot_power(path, t, p_w, max_points=4000):
    """Plot optical power in dBm against time (ms)."""
    plt = _plt()
    with np.errstate(divide='ignore', invalid='ignore'):
        dbm = 10 * np.log10(np.maximum(np.asarray(p_w, float), 1e-15) / 1e-3)
    tt, dd = envelope(t, dbm, max_points)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.plot(tt * 1e3, dd, lw=1.0, label='optical power')
    ax.set_xlabel('time (ms)')
    ax.set_ylabel('optical power (dBm)')
    ax.legend(loc='best')
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def plot_channels(path, m):
    """Plot each array channel's coupling (dB) at the end of the run and at the best pose."""
    plt = _plt()
    n = m['channels']
    ch = np.arange(1, n + 1)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    ax.bar(ch - 0.2, m['coupling_db'], 0.4, label='end of the run')
    ax.bar(ch + 0.2, np.asarray(m['coupling_db']) + np.asarray(m['loss_db']), 0.4,
           label='best joint pose')
    ax.set_xticks(ch)
    ax.set_xlabel('channel (%d and %d measured)' % tuple(m['measured']))
    ax.set_ylabel('coupling (dB)')
    ax.set_title('roll %.3f mrad (best joint pose %.3f mrad)' % (
        m['pose']['roll_rad'] * 1e3, m['best_pose']['roll_rad'] * 1e3))
    ax.legend(loc='upper center', bbox_to_anchor=(0.5, -0.2), ncol=2)
    ax.grid(True, alpha=0.3, axis='y')
    return _save(fig, path)


def make_figures(out_dir, data, max_points=4000):
    """
    Write every figure the data allows into ``out_dir``; return [(title, path)].

    :param data: dict from :func:`fiber_align.analysis.cli.analyze_bag` (``arrays``; its
        ``kind`` ``alignment`` leaves out the tracking error).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = []
    t, y = data.get('t'), data.get('y')
    if t is not None and y is not None and t.size:
        volts = {k.replace('_voltage', ''): data[k] for k in
                 ('feedforward_voltage', 'feedback_voltage', 'drive_voltage') if k in data}
        figs.append(('Setpoint, displacement and voltages',
                     plot_time(out / 'time.png', t, y, data.get('setpoint'), volts,
                               max_points)))
        if 'setpoint' in data and data.get('kind') != 'alignment':
            # an alignment's setpoint is the sequencer's search: no error to follow
            figs.append(('Tracking error', plot_error(out / 'error.png', t, data['setpoint'],
                                                      y, max_points)))
        if 'drive_voltage' in data:
            figs.append(('Voltage-displacement loop',
                         plot_loop(out / 'loop.png', data['drive_voltage'], y)))
    if data.get('gains'):
        figs.append(('Fuzzy PID gains', plot_gains(out / 'gains.png', data['gains_t'],
                                                   data['gains'], max_points)))
    if data.get('power_t') is not None:
        figs.append(('Optical power', plot_power(out / 'optical_power.png', data['power_t'],
                                                 data['power'], max_points)))
    if data.get('array'):
        figs.append(('Array channels', plot_channels(out / 'array_channels.png',
                                                     data['array'])))
    return figs
