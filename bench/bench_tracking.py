# SPDX-License-Identifier: Apache-2.0
"""
The TRACKING demodulator's cost per control period, beside a baseline tree's.

Each TRACKING period adds one reading to :class:`~fiber_align.alignment.tracking.
JointDemodulator` and asks it for the gradient. For ``n`` = 2 (the rig), 3 (the array)
and 4 (the station) axes, dithered at their machine's frequencies: the median of
``--repeats`` timings of ``--updates`` update + gradient calls, in us per period, for this
tree and (``--baseline DIR``, a checkout) the same class of that tree, alternating; their
ratio; and the largest difference of the gradients the two give on the same readings.

``python bench/bench_tracking.py --baseline <checkout>``; without it, this tree only.
"""

import argparse
import importlib.util
import math
from pathlib import Path
import statistics
import sys
import time

import numpy as np

from fiber_align.alignment import tracking

#: axes -> dither frequencies (Hz) of their circles / sines, as the machines run them
CASES = {2: (100.0,), 3: (100.0, 80.0), 4: (100.0, 80.0)}


def _readings(n, count, dt=1e-3, a=0.1e-6):
    """Positions (m) and ``ln P`` of ``count`` periods of the dithers of ``n`` axes."""
    g = np.linspace(0.3e6, -0.2e6, n)
    out = []
    for k in range(count):
        t = k * dt
        pos, i = [], 0
        for f in CASES[n]:
            ph = 2 * math.pi * f * t
            pos += [a * math.cos(ph), a * math.sin(ph)][:n - i]
            i = len(pos)
        out.append((np.array(pos[:n]), -2.0 + float(g @ np.array(pos[:n]))))
    return out


def _time(cls, n, readings):
    dem = cls(n, 0.05, lag_s=0.16e-3)
    t0 = time.perf_counter()
    for pos, lnp in readings:
        dem.update(1e-3, pos, lnp)
        dem.gradient(1e-15)
    return (time.perf_counter() - t0) / len(readings), dem.gradient(1e-15)


def _load(tree):
    spec = importlib.util.spec_from_file_location(
        'baseline_tracking', Path(tree) / 'fiber_align' / 'alignment' / 'tracking.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv=None):
    """Print the table; return 0."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--baseline', help='a checkout to compare with')
    ap.add_argument('--repeats', type=int, default=5)
    ap.add_argument('--updates', type=int, default=2000)
    a = ap.parse_args(argv)
    base = _load(a.baseline) if a.baseline else None
    print('| axes | this: us per period, median | baseline | ratio | gradient difference |')
    print('|---|---|---|---|---|')
    for n in CASES:
        readings = _readings(n, a.updates)
        this, other, g0, g1 = [], [], None, None
        for _ in range(a.repeats):
            t, g0 = _time(tracking.JointDemodulator, n, readings)
            this.append(t)
            if base is not None:
                t, g1 = _time(base.JointDemodulator, n, readings)
                other.append(t)
        m0 = statistics.median(this)
        m1 = statistics.median(other) if other else None
        diff = float(np.max(np.abs(np.asarray(g0) - np.asarray(g1)) / np.abs(g1))) \
            if g1 is not None else None
        print('| %d | %.1f | %s | %s | %s |' % (
            n, m0 * 1e6, '-' if m1 is None else '%.1f' % (m1 * 1e6),
            '-' if m1 is None else '%.2f' % (m0 / m1),
            '-' if diff is None else '%.1e (relative)' % diff))
    return 0


if __name__ == '__main__':
    sys.exit(main())
