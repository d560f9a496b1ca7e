# SPDX-License-Identifier: Apache-2.0
"""
Identify a Prandtl-Ishlinskii model from data ``(t, u, y)`` (s, V, m).

Three methods are offered.

``lsq``
    For fixed thresholds the PI output is linear in the weights, ``y = A w`` with ``A``
    the play-operator outputs (V). Writing ``w = D s`` with ``s`` the partial sums
    (``w_1 = s_1``, ``w_i = s_i - s_{i-1}``) turns the invertibility constraint into
    bounds ``s_i >= eps``; the bounded least-squares problem is solved exactly by
    reducing ``A D`` to its QR factor and running Lawson-Hanson NNLS
    (:func:`scipy.optimize.nnls`) on the ``n x n`` system. Exact optimum.
``pso``
    The paper's method: PSO (150 generations) with the thresholds by the paper's rule
    ``r_i = i / n max(u)`` and the fitness the RMS error (the paper's ``J``). By
    default the particles are the partial sums ``s`` (the loading-curve slopes of the
    paper's section 5.3), so invertibility is the position bound ``s_i >= eps``; with
    ``coordinates: weights`` they are the weights, repaired after every move (partial
    sums clipped to ``eps``).
``pso-thresholds``
    PSO over the thresholds ``r_2 < ... < r_n`` with the weights of every particle
    found by the exact constrained least squares.

Every result model is invertible; :meth:`IdentifyResult.to_json` gives the report.
"""

import contextlib
import copy
from dataclasses import dataclass, field
import json
import time

import numpy as np

from fiber_align.config import load_params
from fiber_align.hysteresis import data as hdata
from fiber_align.hysteresis.pi import PIModel, play_operators
from fiber_align.hysteresis.pso import convergence_generation, pso_minimize

METHODS = ('lsq', 'pso', 'pso-thresholds')
CONFIG_FILE = 'identify.yaml'
CONFIG_NODE = 'identify'


def paper_thresholds(u, n_operators):
    """Return the paper's thresholds ``r_i = i / n max(u)``, i = 0..n-1 (V)."""
    return np.arange(int(n_operators)) * (float(np.max(u)) / int(n_operators))


def partial_sum_basis(ops):
    """
    Return ``A D``: the operator outputs in the partial-sum parametrisation.

    :param ops: operator outputs ``A`` (V), shape ``(..., N, n)``.
    :returns: ``B`` with ``B[..., i] = A[..., i] - A[..., i + 1]`` (last: ``A[..., -1]``),
        so that ``A w = B s`` for partial sums ``s = cumsum(w)``.
    """
    b = ops.copy()
    b[..., :-1] -= ops[..., 1:]
    return b


def bounded_lsq(basis, y, lower):
    """
    Solve ``min ||basis s - y||`` subject to ``s >= lower`` exactly.

    :param basis: matrix ``(N, n)``.
    :param y: targets ``(N,)``.
    :param lower: lower bound of every ``s_i`` (scalar).
    :returns: ``s`` of shape ``(n,)``.
    """
    q, r = np.linalg.qr(basis)
    target = y - basis.sum(axis=1) * lower
    qy = q.T @ target
    try:
        z = np.linalg.solve(r, qy)
    except np.linalg.LinAlgError:
        z = None
    if z is None or np.any(z < 0.0):
        z = _nnls(r, qy, maxiter=50 * r.shape[1])[0]
    return z + lower


def _nnls(a, b, maxiter):
    """Return :func:`scipy.optimize.nnls` of ``a, b``: scipy imported at first use only."""
    # scipy.optimize takes about 0.3 s to import, paid by every process that imports
    # this module (bringup, the CLIs) though few ever identify
    from scipy.optimize import nnls
    return nnls(a, b, maxiter=maxiter)


def bounded_lsq_batch(basis, y, lower):
    """
    Solve :func:`bounded_lsq` for a stack of matrices ``(P, N, n)`` via normal equations.

    Used inside the threshold search, where speed matters and the exact QR solution
    is recomputed for the winner. Only the members whose unconstrained solution breaks
    a bound go through NNLS (on the Cholesky factor of the Gram matrix).

    :returns: ``(s, rms)``: solutions ``(P, n)`` and their RMS residuals ``(P,)`` (unit
        of ``y``).
    """
    n_samples = basis.shape[1]
    target = y[None, :] - basis.sum(axis=2) * lower               # (P, N)
    g = np.einsum('pkn,pkm->pnm', basis, basis)
    h = np.einsum('pkn,pk->pn', basis, target)
    c = np.einsum('pk,pk->p', target, target)
    z = np.full(h.shape, -1.0)
    for p in range(g.shape[0]):
        try:
            chol = np.linalg.cholesky(g[p])
        except np.linalg.LinAlgError:
            z[p] = bounded_lsq(basis[p], y, lower) - lower
            continue
        v = np.linalg.solve(chol, h[p])
        zp = np.linalg.solve(chol.T, v)
        if np.any(zp < 0.0):
            zp = _nnls(chol.T, v, maxiter=50 * g.shape[1])[0]
        z[p] = zp
    sq = c - 2.0 * np.einsum('pn,pn->p', z, h) + np.einsum('pn,pnm,pm->p', z, g, z)
    return z + lower, np.sqrt(np.maximum(sq, 0.0) / n_samples)


def fit_weights(ops, y, eps):
    """
    Return the invertible weights (m/V) that fit ``y`` (m) best for operator outputs ``ops``.

    :param ops: operator outputs (V), shape ``(N, n)``.
    :param eps: lower bound (m/V) of every partial sum of the weights.
    """
    s = bounded_lsq(partial_sum_basis(ops), y, eps)
    return np.diff(s, prepend=0.0)


def repair_weights(w, eps):
    """Clip the partial sums of weights ``(..., n)`` (m/V) to at least ``eps``."""
    s = np.maximum(np.cumsum(w, axis=-1), eps)
    return np.diff(s, axis=-1, prepend=0.0)


def error_vs_voltage(u, err, bins=12):
    """
    Summarise the fit error against voltage (the paper's Figure 16b).

    :param u: voltages (V).
    :param err: errors, model minus measured (m).
    :param bins: number of equal voltage bins.
    :returns: list of dicts with ``voltage_v`` (bin centre), ``rms_error_m``,
        ``max_abs_error_m`` and ``samples``.
    """
    edges = np.linspace(np.min(u), np.max(u), int(bins) + 1)
    idx = np.clip(np.searchsorted(edges, u, side='right') - 1, 0, int(bins) - 1)
    out = []
    for b in range(int(bins)):
        e = err[idx == b]
        if e.size == 0:
            continue
        out.append({'voltage_v': float(0.5 * (edges[b] + edges[b + 1])),
                    'rms_error_m': float(np.sqrt(np.mean(e * e))),
                    'max_abs_error_m': float(np.max(np.abs(e))),
                    'samples': int(e.size)})
    return out


@dataclass
class IdentifyResult:
    """
    The identified model and its fit report (SI units).

    ``history`` holds the best RMS error (m) per generation (empty for ``lsq``);
    ``paper_fitness`` is the paper's fitness ``J``: the RMS error in micrometres.
    """

    model: PIModel
    method: str
    rms_error_m: float
    max_error_m: float
    seconds: float
    history: np.ndarray = field(default_factory=lambda: np.zeros(0))
    converged_generation: int = None
    fitted_m: np.ndarray = field(default=None, repr=False)
    error_vs_voltage: list = field(default_factory=list)
    seed: int = None

    @property
    def paper_fitness(self):
        """Return the paper's fitness value J (RMS error in um, dimensionless number)."""
        return self.rms_error_m * 1e6

    def to_dict(self):
        """Return the report as a JSON-ready mapping (SI units)."""
        return {
            'method': self.method,
            'n_operators': int(self.model.n),
            'rms_error_m': self.rms_error_m,
            'max_error_m': self.max_error_m,
            'paper_fitness_um': self.paper_fitness,
            'thresholds_v': [float(x) for x in self.model.thresholds],
            'weights': [float(x) for x in self.model.weights],
            'weights_unit': 'm/V',
            'min_partial_sum_m_per_v': float(np.min(np.cumsum(self.model.weights))),
            'converged_generation': self.converged_generation,
            'generations': int(max(len(self.history) - 1, 0)),
            'history_rms_error_m': [float(x) for x in self.history],
            'error_vs_voltage': self.error_vs_voltage,
            'seed': self.seed,
            'seconds': self.seconds,
        }

    def to_json(self):
        """Return the report as one JSON object (a string)."""
        return json.dumps(self.to_dict())


def _settings(config, params, settings=None):
    """
    Return the identify settings with overrides applied.

    :param config: params file read when ``settings`` is None (node ``identify``).
    :param params: overrides (nested ``pso``/``pso_thresholds`` merge key by key).
    :param settings: the already loaded ``identify`` parameters (not modified).
    """
    p = copy.deepcopy(load_params(config, CONFIG_NODE) if settings is None else settings)
    for k, v in (params or {}).items():
        if isinstance(v, dict) and isinstance(p.get(k), dict):
            p[k] = dict(p[k], **v)
        else:
            p[k] = v
    return p


class LinearRMS:
    """
    The RMS error ``sqrt(mean((basis x - y)^2))`` of a swarm ``x`` (P, n), evaluated fast.

    With ``basis = Q R`` (thin QR) the squared error is ``|R x - Q^T y|^2 + |y - Q Q^T y|^2``
    exactly, so one generation costs ``P n^2`` instead of ``P N n`` and no large
    matrix product (whose threads fight over a busy machine) is needed. The value is
    the paper's fitness (in m here); nothing of the optimum is used.
    """

    def __init__(self, basis, y):
        """Factor ``basis`` (N, n) and project ``y`` (N,) once."""
        q, self.r = np.linalg.qr(basis)
        self.qy = q.T @ y
        res = y - q @ self.qy
        self.rest = float(res @ res)
        self.n_samples = y.size

    def __call__(self, x):
        """Return the RMS error for every row of ``x``."""
        e = x @ self.r.T - self.qy
        return np.sqrt((np.einsum('pn,pn->p', e, e) + self.rest) / self.n_samples)


def _lsq(u, y, r, eps):
    """Return the constrained least-squares weights for thresholds ``r``."""
    return fit_weights(play_operators(u, r)[0], y, eps)


def _pso_weights(u, y, r, eps, seed, cfg, rel_tol):
    """Run the paper's PSO over the weights; return ``(weights, PSOResult)``."""
    ops = play_operators(u, r)[0]
    slope = float(np.ptp(y) / np.ptp(u))
    bound = float(cfg['bound_factor']) * slope
    n = r.size
    coords = cfg['coordinates']
    if coords == 'partial-sums':
        basis = partial_sum_basis(ops)
        lo, hi = np.full(n, eps), np.full(n, max(bound, 2.0 * eps))
        repair = None
    elif coords == 'weights':
        basis = ops
        lo, hi = np.full(n, -bound), np.full(n, bound)

        def repair(w):
            return repair_weights(w, eps)
    else:
        raise ValueError('pso.coordinates must be partial-sums or weights, got %r' % coords)

    fitness = LinearRMS(basis, y)

    res = pso_minimize(fitness, lo, hi, population=cfg['population'],
                       generations=cfg['generations'], seed=seed,
                       inertia=(cfg['inertia_start'], cfg['inertia_end']),
                       c1=cfg['c1'], c2=cfg['c2'],
                       velocity_fraction=cfg['velocity_fraction'],
                       repair=repair, rel_tol=rel_tol)
    w = np.diff(res.x, prepend=0.0) if coords == 'partial-sums' else res.x
    return w, res


def _pso_thresholds(u, y, n, eps, seed, cfg, rel_tol):
    """Run PSO over thresholds with LSQ weights inside; return ``(r, w, PSOResult)``."""
    umax = float(np.max(np.abs(u)))
    gap = float(cfg['min_gap_fraction']) * umax
    if n < 2:
        raise ValueError('pso-thresholds needs at least 2 operators, got %d' % n)
    if gap * n >= umax:
        raise ValueError('pso_thresholds.min_gap_fraction %g is too large for %d operators'
                         % (cfg['min_gap_fraction'], n))
    lo = np.full(n - 1, gap)
    hi = np.full(n - 1, umax - gap)

    def repair(x):
        x = np.sort(x, axis=-1)
        k = np.arange(1, n)
        # enforce r_i >= r_{i-1} + gap and r_i <= umax - (n - i) gap
        x = np.maximum.accumulate(x - k * gap, axis=-1) + k * gap
        return np.minimum(x, umax - (n - k) * gap)

    def full(x):
        return np.concatenate([np.zeros(x.shape[:-1] + (1,)), x], axis=-1)

    def fitness(x):
        ops = play_operators(u, full(x))[0]                 # (N, P, n)
        basis = partial_sum_basis(np.moveaxis(ops, 0, 1))   # (P, N, n)
        return bounded_lsq_batch(basis, y, eps)[1]

    init = paper_thresholds(u, n)[1:][None, :] if cfg['seed_paper_thresholds'] else None
    res = pso_minimize(fitness, lo, hi, population=cfg['population'],
                       generations=cfg['generations'], seed=seed,
                       inertia=(cfg['inertia_start'], cfg['inertia_end']),
                       c1=cfg['c1'], c2=cfg['c2'],
                       velocity_fraction=cfg['velocity_fraction'],
                       repair=repair, init=init, rel_tol=rel_tol)
    r = full(res.x)
    return r, _lsq(u, y, r, eps), res


def identify(t, u, y, method='lsq', n_operators=None, seed=0, thresholds=None,
             config=CONFIG_FILE, params=None, settings=None):
    """
    Identify an invertible PI model from data.

    :param t: times (s), strictly increasing.
    :param u: drive voltages (V).
    :param y: measured displacements (m).
    :param method: ``lsq``, ``pso`` or ``pso-thresholds``.
    :param n_operators: number of play operators (default from the config, 10).
    :param seed: PSO seed (the result is deterministic for a seed).
    :param thresholds: thresholds (V) for ``lsq``/``pso``; default the paper's rule.
    :param config: params file with the defaults (node ``identify``).
    :param params: overrides of the config values (nested ``pso``/``pso_thresholds``).
    :param settings: the ``identify`` parameters already loaded by the caller (then
        ``config`` is not read).
    :returns: :class:`IdentifyResult`.
    :raises ValueError: bad data or settings, with a message naming the problem.
    """
    cfg = _settings(config, params, settings)
    if method not in METHODS:
        raise ValueError('unknown method %r (allowed: %s)' % (method, ', '.join(METHODS)))
    if thresholds is not None:
        thresholds = np.asarray(thresholds, dtype=float).reshape(-1)
        if n_operators is not None and int(n_operators) != thresholds.size:
            raise ValueError('%d thresholds given for %d operators'
                             % (thresholds.size, int(n_operators)))
        n_operators = thresholds.size
        if method == 'pso-thresholds':
            raise ValueError('pso-thresholds searches the thresholds; do not give them')
    n = int(cfg['n_operators'] if n_operators is None else n_operators)
    if n < 1:
        raise ValueError('the number of operators must be >= 1, got %d' % n)
    t, u, y = hdata.validate(t, u, y, n, thresholds)
    with _single_thread_blas():
        return _identify(t, u, y, method, n, seed, thresholds, cfg)


def _single_thread_blas():
    """
    Return a context that keeps BLAS on one thread (if ``threadpoolctl`` is installed).

    The matrices here are thin (N x 10); threaded BLAS gains nothing on them and, on a
    busy machine, its spinning threads make a 5 ms solve take 100 ms or more.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1, user_api='blas')


def _identify(t, u, y, method, n, seed, thresholds, cfg):
    """Identify with validated inputs (see :func:`identify`)."""
    eps = float(cfg['min_partial_sum_m_per_v'])
    rel_tol = float(cfg['convergence_rel_tol'])
    t0 = time.perf_counter()
    r = thresholds if thresholds is not None else paper_thresholds(u, n)
    history, conv = np.zeros(0), None
    if method == 'lsq':
        PIModel(r, np.ones(n))  # threshold checks with a clear message
        w = _lsq(u, y, r, eps)
    elif method == 'pso':
        PIModel(r, np.ones(n))
        w, res = _pso_weights(u, y, r, eps, seed, dict(cfg['pso']), rel_tol)
        history, conv = res.history, res.converged_generation
    else:
        r, w, res = _pso_thresholds(u, y, n, eps, seed, dict(cfg['pso_thresholds']), rel_tol)
        history, conv = res.history, res.converged_generation
    seconds = time.perf_counter() - t0
    model = PIModel(r, w)  # refuses a non-invertible result
    fitted = model.simulate(u)
    model.reset()
    err = fitted - y
    return IdentifyResult(model=model, method=method,
                          rms_error_m=float(np.sqrt(np.mean(err * err))),
                          max_error_m=float(np.max(np.abs(err))), seconds=seconds,
                          history=np.asarray(history), converged_generation=conv,
                          fitted_m=fitted,
                          error_vs_voltage=error_vs_voltage(u, err, cfg['error_bins']),
                          seed=None if method == 'lsq' else int(seed))


__all__ = ['identify', 'IdentifyResult', 'METHODS', 'paper_thresholds', 'bounded_lsq',
           'fit_weights', 'repair_weights', 'error_vs_voltage', 'convergence_generation']
