# SPDX-License-Identifier: Apache-2.0
"""
Global-best particle swarm optimisation, vectorised over the swarm (pure numpy).

The update is the paper's (section 5.3) with an inertia factor ``w``::

    v <- w v + c1 a1 (pbest - x) + c2 a2 (gbest - x),   v clipped to [vmin, vmax]
    x <- x + v,                                          x clipped to [lb, ub]

``a1``, ``a2`` uniform in [0, 1] per particle and dimension; initial velocities
``vmin + a (vmax - vmin)`` as in the paper. The fitness function takes the whole swarm
``(P, d)`` and returns ``(P,)``, so one generation is one call. An optional ``repair``
maps positions onto the feasible set after every move. Deterministic for a seed.
"""

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PSOResult:
    """
    Outcome of :func:`pso_minimize`.

    ``history[g]`` is the best fitness after generation ``g`` (``history[0]`` is the
    initial swarm); ``converged_generation`` is the first generation whose best is
    within the relative tolerance of the final best.
    """

    x: np.ndarray
    fitness: float
    history: np.ndarray
    converged_generation: int
    evaluations: int
    positions: np.ndarray = field(default=None, repr=False)


def convergence_generation(history, rel_tol=1e-3):
    """Return the first generation whose value is within ``rel_tol`` of the last."""
    h = np.asarray(history, dtype=float)
    final = h[-1]
    ok = h <= final + rel_tol * abs(final)
    return int(np.argmax(ok))


def pso_minimize(fitness, lower, upper, population=40, generations=150, seed=0,
                 inertia=(0.9, 0.4), c1=2.0, c2=2.0, velocity_fraction=0.2,
                 repair=None, init=None, rel_tol=1e-3):
    """
    Minimise ``fitness`` over the box ``[lower, upper]`` by global-best PSO.

    :param fitness: callable ``(P, d) -> (P,)``.
    :param lower: lower position bounds, shape ``(d,)``.
    :param upper: upper position bounds, shape ``(d,)``.
    :param population: number of particles.
    :param generations: number of updates after the initial swarm.
    :param seed: seed of ``numpy.random.default_rng``.
    :param inertia: ``(start, end)``: inertia decreases linearly over the generations.
    :param c1: self learning factor.
    :param c2: group learning factor.
    :param velocity_fraction: ``vmax = fraction * (upper - lower)``, ``vmin = -vmax``.
    :param repair: optional callable ``(P, d) -> (P, d)`` onto the feasible set.
    :param init: optional positions ``(k, d)`` that replace the first ``k`` particles.
    :param rel_tol: relative tolerance of the convergence generation.
    :returns: :class:`PSOResult`.
    """
    lo = np.asarray(lower, dtype=float).reshape(-1)
    hi = np.asarray(upper, dtype=float).reshape(-1)
    if lo.shape != hi.shape or np.any(hi <= lo):
        raise ValueError('PSO bounds need lower < upper in every dimension')
    population, generations = int(population), int(generations)
    if population < 2 or generations < 1:
        raise ValueError('PSO needs population >= 2 and generations >= 1 (got %d, %d)'
                         % (population, generations))
    rng = np.random.default_rng(seed)
    d = lo.size
    vmax = float(velocity_fraction) * (hi - lo)
    x = lo + rng.random((population, d)) * (hi - lo)
    if init is not None:
        init = np.atleast_2d(np.asarray(init, dtype=float))[:population]
        x[:init.shape[0]] = np.clip(init, lo, hi)
    v = -vmax + rng.random((population, d)) * (2.0 * vmax)
    if repair is not None:
        x = repair(x)
    f = np.asarray(fitness(x), dtype=float)
    f = np.where(np.isfinite(f), f, np.inf)
    pbest, pbest_f = x.copy(), f.copy()
    g = int(np.argmin(pbest_f))
    history = [pbest_f[g]]
    w0, w1 = inertia
    for gen in range(generations):
        w = w0 + (w1 - w0) * (gen / max(generations - 1, 1))
        a1 = rng.random((population, d))
        a2 = rng.random((population, d))
        v = w * v + c1 * a1 * (pbest - x) + c2 * a2 * (pbest[g] - x)
        np.clip(v, -vmax, vmax, out=v)
        x = np.clip(x + v, lo, hi)
        if repair is not None:
            x = repair(x)
        f = np.asarray(fitness(x), dtype=float)
        f = np.where(np.isfinite(f), f, np.inf)
        better = f < pbest_f
        pbest[better] = x[better]
        pbest_f[better] = f[better]
        g = int(np.argmin(pbest_f))
        history.append(pbest_f[g])
    history = np.asarray(history)
    return PSOResult(x=pbest[g].copy(), fitness=float(pbest_f[g]), history=history,
                     converged_generation=convergence_generation(history, rel_tol),
                     evaluations=population * (generations + 1), positions=x)
