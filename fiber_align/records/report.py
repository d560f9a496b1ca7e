# SPDX-License-Identifier: Apache-2.0
"""
The catalogue's process report: yield against a loss limit, capability, control charts.

Over the alignments a selection keeps (:func:`~.query.columns`), per machine and in all:

* yield: the share of alignments that ended TRACKING with a final loss at or under the
  upper specification limit ``usl_db`` (dB); an alignment without a loss (no light)
  fails;
* Cpk and Ppk of the final loss against the one-sided upper limit:
  ``(USL - mean) / (3 sigma)``, sigma within (``Cpk``: the mean moving range of
  consecutive alignments over d2 = 1.128) or overall (``Ppk``: the sample standard
  deviation), over the alignments with a loss;
* an individuals and moving-range chart per machine (time order): centre lines, limits
  ``mean +- 2.66 MRbar`` and ``3.267 MRbar``, points beyond them marked;
* histograms of the final loss (with the limit) and of the time to peak.

:func:`figures` writes PNGs (matplotlib, Agg) and :func:`markdown` the page that shows
them with the table; :func:`write` does both.
"""

import math
import os

import numpy as np

#: The state an alignment that passed ends in.
PASS_STATE = 'TRACKING'
#: Control chart constants for moving ranges of two: d2, the I chart's 3/d2, D4.
D2 = 1.128
E2 = 3.0 / D2
D4 = 3.267
ALL = 'all'


def stats(loss_db, state, ttp_s, usl_db):
    """
    Return the figures of one group (arrays in time order; SI, dB).

    :returns: dict ``n``, ``n_loss``, ``passed``, ``yield``, ``mean_loss_db``,
        ``sigma_within_db``, ``sigma_overall_db``, ``cpk``, ``ppk``,
        ``median_time_to_peak_s``, ``i_out`` and ``mr_out`` (points beyond the limits).
    """
    n = int(len(loss_db))
    ok_loss = np.isfinite(loss_db)
    x = loss_db[ok_loss]
    passed = int(np.count_nonzero((state == PASS_STATE) & ok_loss
                                  & (np.where(ok_loss, loss_db, np.inf) <= usl_db)))
    out = dict(n=n, n_loss=int(len(x)), passed=passed, usl_db=float(usl_db),
               **{'yield': passed / n if n else None})
    mean = float(np.mean(x)) if len(x) else None
    mr = np.abs(np.diff(x))
    s_within = float(np.mean(mr) / D2) if len(mr) else None
    s_overall = float(np.std(x, ddof=1)) if len(x) > 1 else None
    out.update(mean_loss_db=mean, sigma_within_db=s_within, sigma_overall_db=s_overall,
               cpk=_capability(usl_db, mean, s_within),
               ppk=_capability(usl_db, mean, s_overall))
    t = ttp_s[np.isfinite(ttp_s)]
    out['median_time_to_peak_s'] = float(np.median(t)) if len(t) else None
    lim = limits(x)
    out['i_out'] = int(np.count_nonzero((x > lim['i_ucl']) | (x < lim['i_lcl']))) \
        if lim else 0
    out['mr_out'] = int(np.count_nonzero(mr > lim['mr_ucl'])) if lim else 0
    return out


def _capability(usl, mean, sigma):
    if mean is None or not sigma:
        return None
    return (usl - mean) / (3.0 * sigma)


def limits(x):
    """Return the I-MR chart's centre lines and limits of ``x`` (dB), or None (< 2 points)."""
    if len(x) < 2:
        return None
    mean, mrbar = float(np.mean(x)), float(np.mean(np.abs(np.diff(x))))
    return dict(i_cl=mean, i_ucl=mean + E2 * mrbar, i_lcl=mean - E2 * mrbar, mr_cl=mrbar,
                mr_ucl=D4 * mrbar)


def groups(cols):
    """Return ``[(name, mask)]``: each machine, then ``all``."""
    names, which = np.unique(cols['machine'].astype(str), return_inverse=True)
    return [(str(m), which == i) for i, m in enumerate(names)] + [(ALL, np.ones(len(
        cols['machine']), bool))]


def summary(cols, usl_db):
    """Return ``{group: stats}`` of :func:`groups`."""
    out = {name: stats(cols['final_loss_db'][m], cols['final_state'][m],
                       cols['time_to_peak_s'][m], usl_db) for name, m in groups(cols)}
    if len(out) > 2:        # consecutive alignments of different machines: no within sigma
        out[ALL].update(sigma_within_db=None, cpk=None, i_out=None, mr_out=None)
    return out


def figures(cols, usl_db, out_dir):
    """Write the report's PNGs into ``out_dir``; return their file names."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    names = []
    machines = [(n, m) for n, m in groups(cols) if n != ALL]
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    for name, m in machines:
        x = cols['final_loss_db'][m]
        x = x[np.isfinite(x)]
        ax[0].hist(x, bins=_bins(len(x)), histtype='step', label=name)
        t = cols['time_to_peak_s'][m]
        t = t[np.isfinite(t) & (t > 0)] * 1e3
        if len(t):
            ax[1].hist(t, bins=np.geomspace(t.min(), t.max() * 1.0001, _bins(len(t)) + 1),
                       histtype='step', label=name)
    ax[0].axvline(usl_db, color='r', linestyle='--', label='USL %.3g dB' % usl_db)
    ax[0].set_xlabel('final coupling loss (dB)')
    ax[0].set_ylabel('alignments')
    ax[0].set_title('final loss per machine')
    ax[1].set_xscale('log')
    ax[1].set_xlabel('time to peak (ms, log scale)')
    ax[1].set_title('time to peak per machine')
    for a in ax:
        a.legend()
        a.grid(alpha=0.3)
    fig.tight_layout()
    names.append('histograms.png')
    fig.savefig(os.path.join(out_dir, names[-1]), dpi=100)
    plt.close(fig)
    for name, m in machines:
        finite = np.isfinite(cols['final_loss_db']) & m
        x = cols['final_loss_db'][finite]
        lim = limits(x)
        if lim is None:
            continue
        names.append('imr_%s.png' % _safe(name))
        _imr_chart(plt, x, as_datetimes(cols['started_at'][finite]), lim, name, usl_db,
                   os.path.join(out_dir, names[-1]))
    return names


def as_datetimes(started_at):
    """Return the catalogue's time texts (UTC) as numpy datetimes (microseconds)."""
    return np.array([str(t)[:26] for t in started_at], dtype='datetime64[us]')


def _imr_chart(plt, x, when, lim, name, usl_db, path):
    """
    Write the individuals and moving-range chart of one machine (``x`` dB, time order).

    The x axis is the alignments' order (a control chart's), labelled with their start
    times (``when``): alignments of one run may share a start.
    """
    from matplotlib.ticker import FuncFormatter, MaxNLocator
    fig, ax = plt.subplots(2, 1, figsize=(13, 6.5), sharex=True)
    t = np.arange(len(x))
    labels = np.datetime_as_string(when, unit='m')

    def label(v, _pos):
        i = int(round(v))
        return labels[i].replace('T', '\n') if 0 <= i < len(labels) else ''
    ax[1].xaxis.set_major_locator(MaxNLocator(8, integer=True))
    ax[1].xaxis.set_major_formatter(FuncFormatter(label))
    mr = np.abs(np.diff(x))
    dense = len(x) > 2000        # a week of a line: dots and a rolling mean read better
    style = dict(ls='none', marker='.', ms=1.5, alpha=0.5) if dense else \
        dict(lw=0.8, marker='.', ms=4)
    ax[0].plot(t, x, color='C0', label='alignments', **style)
    ax[1].plot(t[1:], mr, color='C1', **style)
    w = max(2, len(x) // 200)
    if dense:
        k = np.ones(w) / w
        ax[0].plot(t[w - 1:], np.convolve(x, k, 'valid'), color='k', lw=1.2,
                   label='mean of %d' % w)
        ax[1].plot(t[w:], np.convolve(mr, k, 'valid'), color='k', lw=1.2)
    bad = (x > lim['i_ucl']) | (x < lim['i_lcl'])
    ax[0].plot(t[bad], x[bad], 'o', color='r', ms=3, label='beyond limits (%d)'
               % np.count_nonzero(bad))
    for key, ls in (('i_cl', '-'), ('i_ucl', '--'), ('i_lcl', '--')):
        ax[0].axhline(lim[key], color='0.3', linestyle=ls, lw=0.9)
    ax[0].axhline(usl_db, color='r', linestyle=':', lw=1.2, label='USL %.3g dB' % usl_db)
    ax[0].set_ylabel('final loss (dB)')
    ax[0].set_title('%s: individuals (CL %.4g dB, UCL %.4g dB, LCL %.4g dB, n %d)'
                    % (name, lim['i_cl'], lim['i_ucl'], lim['i_lcl'], len(x)))
    ax[0].legend(loc='upper left', bbox_to_anchor=(1.0, 1.0), fontsize=8)
    ax[1].axhline(lim['mr_cl'], color='0.3', lw=0.9)
    ax[1].axhline(lim['mr_ucl'], color='0.3', linestyle='--', lw=0.9)
    ax[1].set_ylabel('moving range (dB)')
    ax[1].set_xlabel('alignments in time order, labelled by their start (UTC)')
    ax[1].set_title('moving range of consecutive alignments (CL %.4g dB, UCL %.4g dB)'
                    % (lim['mr_cl'], lim['mr_ucl']))
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _bins(n):
    """Return a histogram's bin count for ``n`` values (sqrt rule, 10 to 60)."""
    return int(np.clip(np.sqrt(max(n, 1)), 10, 60))


def _safe(name):
    return ''.join(c if c.isalnum() or c in '-_' else '_' for c in name)


def _f(v, fmt='%.3f', scale=1.0):
    return '-' if v is None or (isinstance(v, float) and not math.isfinite(v)) \
        else fmt % (v * scale)


def markdown(table, pngs, usl_db, title):
    """Return the report page (markdown) of :func:`summary`'s ``table`` and the PNG names."""
    lines = ['# %s' % title, '',
             'Upper specification limit of the final coupling loss: %g dB. Yield: alignments '
             'that ended %s with a final loss at or under it. Cpk uses the within sigma (mean '
             'moving range / %.3f), Ppk the overall sigma; over all machines together only '
             'Ppk (consecutive alignments of two machines make no moving range).'
             % (usl_db, PASS_STATE, D2), '',
             '| machine | alignments | with loss | passed | yield % | mean loss dB | '
             'sigma within dB | sigma overall dB | Cpk | Ppk | median time to peak ms | '
             'I beyond | MR beyond |', '|' + '---|' * 13]
    for name, s in table.items():
        lines.append('| %s | %d | %d | %d | %s | %s | %s | %s | %s | %s | %s | %s | %s |' % (
            name, s['n'], s['n_loss'], s['passed'], _f(s['yield'], '%.2f', 100.0),
            _f(s['mean_loss_db'], '%.4f'), _f(s['sigma_within_db'], '%.4f'),
            _f(s['sigma_overall_db'], '%.4f'), _f(s['cpk'], '%.2f'), _f(s['ppk'], '%.2f'),
            _f(s['median_time_to_peak_s'], '%.1f', 1e3), _f(s['i_out'], '%d'),
            _f(s['mr_out'], '%d')))
    lines.append('')
    for p in pngs:
        lines += ['![%s](%s)' % (p[:-4], p), '']
    return '\n'.join(lines)


def write(cols, usl_db, out_dir, title='Alignment report'):
    """Write the figures and ``report.md`` into ``out_dir``; return the summary table."""
    os.makedirs(out_dir, exist_ok=True)
    table = summary(cols, usl_db)
    pngs = figures(cols, usl_db, out_dir)
    with open(os.path.join(out_dir, 'report.md'), 'w', encoding='utf-8') as f:
        f.write(markdown(table, pngs, usl_db, title))
    return table
