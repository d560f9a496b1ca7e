# SPDX-License-Identifier: Apache-2.0
"""
Speed of the design model: many-geometry sweeps and one full report.

Goal (issue 2): 1,000 geometries (free displacement, blocked force of trapezoid and
rectangle, tip stiffness, first mode) in well under a second. Run with
``python -m bench bench_design``; prints a Markdown table (times in ms, best of 3).
"""

import time

import numpy as np

from fiber_align.design import load_actuator, report
from fiber_align.design.model import tip_displacement
from fiber_align.design.sweeps import evaluate, sweep


def _best(fn, repeat=3):
    """Return the best wall time of ``fn()`` over ``repeat`` runs, s."""
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _random_geometries(base, n, seed=0):
    """Return ``n`` random geometries around ``base`` spanning the Figure 7-10 ranges (SI)."""
    rng = np.random.default_rng(seed)
    g = {k: np.full(n, v, dtype=float) for k, v in base.geometry().items()}
    g['A'] = rng.uniform(6e-3, 10e-3, n)
    g['L'] = rng.uniform(6e-3, 18e-3, n)
    g['L0'] = g['L'] + 0.5e-3
    g['hp'] = rng.uniform(50e-6, 150e-6, n)
    g['hb'] = g['hp'] * rng.uniform(0.5, 1.5, n)
    return g


def main():
    """Print the benchmark table (Markdown)."""
    base = load_actuator('actuator_table1.yaml')
    n = 1000
    g = _random_geometries(base, n)
    ns, nf = base.sweep_fe_elements, base.fe_elements
    rows = [
        ('equation 5 only, %d geometries' % n, '-',
         _best(lambda: tip_displacement(100.0, **g)), '-'),
        ('beam FE, %d geometries (trapezoid + rectangle)' % n, ns,
         _best(lambda: evaluate(100.0, n_elements=ns, **g)), '< 1000 ms (sweeps)'),
        ('Figure 8 sweep, %d points' % n, ns, _best(lambda: sweep(base, 'L', n=n)),
         '< 1000 ms (sweeps)'),
        ('beam FE, %d geometries (trapezoid + rectangle)' % n, nf,
         _best(lambda: evaluate(100.0, n_elements=nf, **g)), '- (single-design mesh)'),
        ('one full report (design CLI numbers)', nf, _best(lambda: report(base, 100.0)),
         '-'),
    ]
    print('| case | FE elements | time (ms) | goal |')
    print('|---|---|---|---|')
    for name, ne, t, goal in rows:
        print('| %s | %s | %.3f | %s |' % (name, ne, t * 1e3, goal))


if __name__ == '__main__':
    main()
