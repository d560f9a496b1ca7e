# SPDX-License-Identifier: Apache-2.0
"""
Identification data: CSV loading, validation and the paper's experiment signal.

Units: time in s, voltage in V, displacement in m. The CSV has a header with the
columns ``t``, ``voltage_v`` and ``displacement_m`` (any order, extra columns ignored).
"""

import csv
from pathlib import Path

import numpy as np

COLUMNS = ('t', 'voltage_v', 'displacement_m')


def triangle(t, amplitude=72.0, freq=0.1, offset=0.0):
    """
    Return a triangle wave that starts at ``offset`` and peaks at ``offset + amplitude``.

    :param t: times (s).
    :param amplitude: peak-to-peak amplitude (V).
    :param freq: frequency (Hz); the first peak is at ``1 / (2 freq)``.
    :param offset: value at t = 0 (V).
    :returns: voltages (V), same shape as ``t``.
    """
    ph = np.mod(np.asarray(t, dtype=float) * float(freq), 1.0)
    return offset + amplitude * (1.0 - np.abs(1.0 - 2.0 * ph))


def experiment_signal(v_max=72.0, freq=0.1, periods=1, n_samples=2001):
    """
    Return ``(t, u)`` for the paper's hysteresis experiment, 0..v_max triangle.

    The paper drove 0-72 V at 0.1 Hz (5 V generator, amplified). ``n_samples`` samples
    are spread evenly over ``periods`` periods, both ends included.

    :param v_max: peak voltage (V).
    :param freq: frequency (Hz).
    :param periods: number of periods.
    :param n_samples: number of samples.
    :returns: times (s) and voltages (V).
    """
    t = np.linspace(0.0, periods / float(freq), int(n_samples))
    return t, triangle(t, v_max, freq)


def load_csv(path):
    """
    Read ``t, voltage_v, displacement_m`` from a CSV file with a header row.

    :returns: ``(t, u, y)`` in s, V, m as float arrays.
    :raises ValueError: missing file or column, or a value that is not a number.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError('data file %s does not exist (give a CSV with columns %s or a '
                         'rosbag2 directory)' % (p, ', '.join(COLUMNS)))
    with open(p, newline='', encoding='utf-8') as f:
        reader = csv.reader(f)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise ValueError('%s is empty; it needs a header %s' % (p, ','.join(COLUMNS)))
        missing = [c for c in COLUMNS if c not in header]
        if missing:
            raise ValueError('%s lacks column(s) %s (header has: %s; needs %s)'
                             % (p, ', '.join(missing), ', '.join(header), ','.join(COLUMNS)))
        idx = [header.index(c) for c in COLUMNS]
        rows = []
        for line_no, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            try:
                rows.append([float(row[i]) for i in idx])
            except (IndexError, ValueError):
                raise ValueError('%s line %d: expected numbers in columns %s, got %r'
                                 % (p, line_no, ', '.join(COLUMNS), row)) from None
    if not rows:
        raise ValueError('%s has a header but no data rows' % p)
    a = np.asarray(rows, dtype=float)
    return a[:, 0], a[:, 1], a[:, 2]


def save_csv(path, t, u, y):
    """Write ``t`` (s), ``u`` (V), ``y`` (m) as a CSV with the standard header."""
    with open(path, 'w', newline='', encoding='utf-8') as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for row in zip(np.asarray(t).tolist(), np.asarray(u).tolist(),
                       np.asarray(y).tolist()):
            w.writerow(['%.9g' % row[0], '%.9g' % row[1], '%.9g' % row[2]])


def validate(t, u, y, n_operators, thresholds=None):
    """
    Check identification data and return it as float arrays ``(t, u, y)``.

    :param t: times (s), strictly increasing.
    :param u: voltages (V), not constant.
    :param y: displacements (m).
    :param n_operators: number of play operators to identify; needs at least as
        many samples.
    :param thresholds: thresholds (V) to be used, if known; each operator must become
        active somewhere in the data (starting at rest, operator ``i`` stays at 0
        unless ``|u| > r_i``).
    :raises ValueError: with a message naming the problem and what is allowed.
    """
    arrays = {}
    for name, a in (('t', t), ('voltage_v', u), ('displacement_m', y)):
        a = np.asarray(a, dtype=float)
        if a.ndim != 1:
            raise ValueError('%s must be one-dimensional, got shape %s' % (name, a.shape))
        arrays[name] = a
    lengths = {k: v.size for k, v in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError('columns have unequal lengths (%s); t, voltage_v and '
                         'displacement_m need one value per sample'
                         % ', '.join('%s: %d' % kv for kv in lengths.items()))
    for name, a in arrays.items():
        bad = np.nonzero(~np.isfinite(a))[0]
        if bad.size:
            raise ValueError('%s has %d non-finite value(s) (NaN or inf), first at sample %d; '
                             'all values must be finite' % (name, bad.size, bad[0]))
    t, u, y = arrays['t'], arrays['voltage_v'], arrays['displacement_m']
    n_operators = int(n_operators)
    if n_operators < 1:
        raise ValueError('the number of operators must be >= 1, got %d' % n_operators)
    if t.size < max(n_operators, 2):
        raise ValueError('%d samples are fewer than the %d operators to identify; need at '
                         'least as many samples as operators' % (t.size, n_operators))
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0)) + 1
        raise ValueError('time is not strictly increasing at sample %d (t = %.9g s after '
                         '%.9g s)' % (k, t[k], t[k - 1]))
    span = float(u.max() - u.min())
    if span <= 1e-9 * max(1.0, float(np.abs(u).max())):
        raise ValueError('the voltage is constant (%.6g V); identification needs a drive '
                         'that sweeps the voltage range, e.g. the 0-72 V triangle' % u[0])
    if u.max() <= 0.0:
        raise ValueError('the voltage never rises above 0 V (max %.6g V); the drive must '
                         'be positive' % u.max())
    if thresholds is not None:
        r = np.asarray(thresholds, dtype=float).reshape(-1)
        reach = float(np.abs(u).max())
        idle = np.nonzero(r[1:] >= reach)[0]
        if idle.size:
            i = int(idle[0]) + 1
            raise ValueError('operator %d (threshold %.6g V) is never active: the voltage '
                             'stays within +-%.6g V; every threshold must be below the '
                             'largest |voltage|' % (i + 1, r[i], reach))
    return t, u, y
