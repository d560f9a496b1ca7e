# SPDX-License-Identifier: Apache-2.0
"""
Benchmark PI identification on 2,000 samples of the 0.1 Hz, 0-72 V triangle.

Prints a Markdown table (medians): ``lsq``, the paper's ``pso`` (150 generations),
``pso-thresholds`` and pyswarms' GlobalBestPSO on the same objective (partial-sum
coordinates, same bounds, swarm size and generations, its default options, the best
of its boundary handlers), with the final RMS error. Data: dense-PI and Bouc-Wen
truths plus 10 nm RMS noise.
"""

import logging
import statistics
import time

import numpy as np

from fiber_align.hysteresis import data
from fiber_align.hysteresis.identify import (identify, LinearRMS, paper_thresholds,
                                             partial_sum_basis)
from fiber_align.hysteresis.pi import play_operators
from fiber_align.hysteresis.truth import make_hysteresis


def _timed(fn, repeats):
    """Return ``(median seconds, last result)`` of ``repeats`` calls of ``fn``."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _pyswarms(u, y, population=100, generations=150, seed=0):
    """Run pyswarms GlobalBestPSO on the paper objective; return {handler: (s, rms)}."""
    try:
        import pyswarms
    except ImportError:
        return {}
    logging.getLogger('pyswarms').setLevel(logging.ERROR)
    basis = partial_sum_basis(play_operators(u, paper_thresholds(u, 10))[0])
    f = LinearRMS(basis, y)
    slope = float(np.ptp(y) / np.ptp(u))
    bounds = (np.full(10, 1e-9), np.full(10, 2.0 * slope))
    out = {}
    # 'reflective' is left out: pyswarms reflects in a loop until every coordinate is in
    # bounds, and with velocities of this objective's scale that ran for minutes (seen
    # hanging in BoundaryHandler.reflective).
    for bh in ('nearest', 'shrink', 'periodic'):
        np.random.seed(seed)
        opt = pyswarms.single.GlobalBestPSO(
            n_particles=population, dimensions=10,
            options={'c1': 0.5, 'c2': 0.3, 'w': 0.9}, bounds=bounds, bh_strategy=bh)
        t0 = time.perf_counter()
        cost, _ = opt.optimize(f, iters=generations, verbose=False)
        out[bh] = (time.perf_counter() - t0, float(cost))
    return out


def main():
    """Run the benchmark and print the Markdown table."""
    rows = []
    t, u = data.experiment_signal(n_samples=2000)
    for kind in ('dense-pi', 'bouc-wen'):
        y = make_hysteresis(kind).simulate(u) + np.random.default_rng(0).normal(0, 1e-8, u.size)
        s, r = _timed(lambda: identify(t, u, y, 'lsq'), 7)
        ref = r.rms_error_m
        rows.append((kind, 'lsq (exact, paper thresholds)', s, ref))
        s, r = _timed(lambda: identify(t, u, y, 'pso', seed=0), 3)
        rows.append((kind, 'pso (paper, 150 gen, 100 particles)', s, r.rms_error_m))
        ps = _pyswarms(u, y)
        if ps:
            best = min(ps, key=lambda k: ps[k][1])
            rows.append((kind, 'pyswarms GlobalBestPSO (150 it, 100 p, bh=%s)' % best,
                         ps[best][0], ps[best][1]))
        s, r = _timed(lambda: identify(t, u, y, 'pso-thresholds', seed=0), 1)
        rows.append((kind, 'pso-thresholds (150 gen, 20 p)', s, r.rms_error_m))
        rows.append((kind, '_ref', 0.0, ref))
    print('| data | method | time (s, median) | final RMS (um) | RMS / lsq |')
    print('|---|---|---:|---:|---:|')
    ref = None
    for kind, name, s, rms in rows:
        if name == '_ref':
            continue
        if name.startswith('lsq'):
            ref = rms
        print('| %s | %s | %.4f | %.4f | %.3f |' % (kind, name, s, rms * 1e6, rms / ref))


if __name__ == '__main__':
    main()
