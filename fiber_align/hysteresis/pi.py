# SPDX-License-Identifier: Apache-2.0
"""
Prandtl-Ishlinskii (PI) hysteresis: play operators, the model and its exact inverse.

Units: input voltage in V, thresholds in V, weights in m/V, output displacement in m.
The inverse model maps displacement (m) to voltage (V); its thresholds are in m.

Play operator with threshold r (SEED-NOTES section 4)::

    y(k) = max(u(k) - r, min(u(k) + r, y(k-1)))

PI output ``Y(k) = sum_i w_i y_i(k)``. With ``r_1 = 0 < r_2 < ... < r_n`` the initial
loading curve has slope ``w_1 + ... + w_i`` on ``[r_i, r_{i+1}]``; the model is
invertible exactly when every partial sum is positive, and its inverse is again a PI
model (Kuhnen / Krejci), computed by :meth:`PIModel.inverse`.
"""

import numpy as np

from fiber_align.config import ConfigError, load_params, write_params
from fiber_align.hysteresis.playbank import PlayBank


class NotInvertibleError(ValueError):
    """The weights have a non-positive partial sum; the model has no inverse."""


def _segments(u):
    """
    Split an input sequence into monotone runs.

    :param u: input sequence, shape ``(N,)``.
    :returns: list of ``(start, stop, direction)`` with direction +1 (non-decreasing)
        or -1 (non-increasing); flat samples join the run they are in.
    """
    d = np.sign(np.diff(u))
    nz = np.nonzero(d)[0]
    if nz.size == 0:
        return [(0, u.size, 1)]
    dirs = d[nz]
    change = nz[1:][dirs[1:] != dirs[:-1]]  # diff index where the direction flips
    starts = np.concatenate([[0], change + 1])
    stops = np.concatenate([change + 1, [u.size]])
    first = [int(dirs[0])] + [int(d[c]) for c in change]
    return list(zip(starts.tolist(), stops.tolist(), first))


def play_operators(u, thresholds, state=None):
    """
    Run a bank of play operators over an input sequence.

    Operator ``i`` follows ``y(k) = max(u(k) - r_i, min(u(k) + r_i, y(k-1)))``.
    Within a run where ``u`` does not decrease this is ``max(u(k) - r, y0)`` and where
    it does not increase ``min(u(k) + r, y0)`` (``y0`` the state at the run start),
    so the work is vectorised over samples, operators and any leading axes; inputs with
    many reversals (noise) fall back to a per-sample loop vectorised over operators.
    Both paths give bit-identical results.

    :param u: input sequence, shape ``(N,)`` (V for the forward model, m for the inverse).
    :param thresholds: thresholds, shape ``(..., n)`` (same unit as ``u``); leading
        axes (e.g. a particle swarm) are vectorised over.
    :param state: operator outputs before the first sample, shape like ``thresholds``;
        default all zero (at rest with u = 0).
    :returns: ``(outputs, final_state)``; outputs has shape ``(N,) + thresholds.shape``.
    """
    u = np.asarray(u, dtype=float).reshape(-1)
    r = np.asarray(thresholds, dtype=float)
    y = np.zeros(r.shape) if state is None else np.array(state, dtype=float, copy=True)
    if y.shape != r.shape:
        raise ValueError('state shape %s does not match thresholds shape %s'
                         % (y.shape, r.shape))
    out = np.empty((u.size,) + r.shape)
    if u.size == 0:
        return out, y
    # The first sample may move either way from the state; do it the general way.
    np.minimum(u[0] + r, y, out=y)
    np.maximum(u[0] - r, y, out=y)
    out[0] = y
    if u.size == 1:
        return out, y.copy()
    segs = _segments(u[1:])
    if len(segs) * 8 < u.size:
        bshape = (-1,) + (1,) * r.ndim
        for a, b, direction in segs:
            uu = u[1 + a:1 + b].reshape(bshape)
            blk = out[1 + a:1 + b]
            if direction > 0:
                np.maximum(uu - r, y, out=blk)
            else:
                np.minimum(uu + r, y, out=blk)
            y = blk[-1].copy()
        return out, y
    lo_off = -r
    for k in range(1, u.size):
        uk = u[k]
        np.minimum(uk + r, y, out=y)
        np.maximum(uk + lo_off, y, out=y)
        out[k] = y
    return out, y.copy()


def check_thresholds(thresholds):
    """Validate thresholds: finite, first one 0, strictly increasing. Returns an array."""
    r = np.asarray(thresholds, dtype=float).reshape(-1)
    if r.size == 0:
        raise ValueError('a PI model needs at least one operator')
    if not np.all(np.isfinite(r)):
        raise ValueError('thresholds must be finite')
    if r[0] != 0.0:
        raise ValueError('the first threshold must be 0 (got %g); it carries the '
                         'linear part that makes the model invertible' % r[0])
    if np.any(np.diff(r) <= 0):
        i = int(np.argmax(np.diff(r) <= 0)) + 1
        raise ValueError('thresholds must be strictly increasing; threshold %d (%g) '
                         'is not above threshold %d (%g)' % (i + 1, r[i], i, r[i - 1]))
    return r


def first_bad_partial_sum(weights):
    """Return the 0-based index of the first partial sum <= 0, or ``None``."""
    s = np.cumsum(np.asarray(weights, dtype=float))
    bad = np.nonzero(s <= 0)[0]
    return int(bad[0]) if bad.size else None


class _PlayModel:
    """
    Weighted play operators ``Y = sum_i w_i s_i``: what the model and its inverse share.

    Stepping is :class:`~fiber_align.hysteresis.playbank.PlayBank` (exact, amortised O(1)
    per sample); whole sequences go through :func:`play_operators` (vectorised). The
    bank holds the operator state, so the two stay one state.
    """

    def _init_bank(self, state):
        """Build the bank at rest (zeros), then put it at ``state`` (None: rest)."""
        self._bank = PlayBank(self.thresholds, self.weights)
        self._bank.reset(self._check_state(state))

    def _check_state(self, state):
        """Return ``state`` as a list of finite floats, one per operator (None: zeros)."""
        if state is None:
            return [0.0] * self.thresholds.size
        st = np.asarray(state, dtype=float)
        if st.size != self.thresholds.size or not np.all(np.isfinite(st)):
            raise ValueError('state needs %d finite values, got %s'
                             % (self.thresholds.size, st.shape))
        return st.reshape(-1).tolist()

    @property
    def n(self):
        """Return the number of play operators."""
        return self.thresholds.size

    @property
    def state(self):
        """Return the present operator outputs (input unit), a copy."""
        return np.asarray(self._bank.state, dtype=float)

    def step(self, u):
        """Advance one sample with input ``u``; return the output (see the class)."""
        return self._bank.step(u)

    def simulate(self, u, reset=True):
        """
        Run an input sequence and return the output sequence.

        :param reset: start from the initial state (default) rather than the present one.
        """
        if reset:
            self.reset()
        ops, final = play_operators(u, self.thresholds, self.state)
        self._bank.reset(final.tolist())
        return ops @ self.weights


class PIModel(_PlayModel):
    """
    A Prandtl-Ishlinskii model ``u (V) -> y (m)``.

    :param thresholds: play thresholds in V, ``0 = r_1 < ... < r_n``.
    :param weights: operator weights in m/V.
    :param state: operator outputs (V) before the next sample; default at rest (zeros).
    :param require_invertible: refuse weights with a non-positive partial sum.
    """

    def __init__(self, thresholds, weights, state=None, require_invertible=True):
        """Check and store the parameters (V, m/V) and the operator state (V)."""
        self.thresholds = check_thresholds(thresholds)
        self.weights = np.asarray(weights, dtype=float).reshape(-1)
        self.require_invertible = bool(require_invertible)
        if self.weights.shape != self.thresholds.shape:
            raise ValueError('%d weights for %d thresholds'
                             % (self.weights.size, self.thresholds.size))
        if not np.all(np.isfinite(self.weights)):
            raise ValueError('weights must be finite')
        if self.require_invertible:
            bad = first_bad_partial_sum(self.weights)
            if bad is not None:
                raise NotInvertibleError(
                    'not invertible: partial sum of weights 1..%d is %.6g <= 0 (first bad '
                    'index %d); every partial sum w_1 + ... + w_i must be > 0'
                    % (bad + 1, float(np.sum(self.weights[:bad + 1])), bad + 1))
        self._init_bank(state)

    def __repr__(self):
        """Return a short description (thresholds in V, weights in m/V)."""
        return 'PIModel(thresholds=%r, weights=%r)' % (self.thresholds.tolist(),
                                                       self.weights.tolist())

    @property
    def state(self):
        """Return the present operator outputs (V), a copy."""
        return _PlayModel.state.fget(self)

    @state.setter
    def state(self, value):
        """Set the operator outputs (V)."""
        self.reset(value)

    def reset(self, state=None):
        """Put the operators back at rest, or at ``state`` (V per operator)."""
        self._bank.reset(self._check_state(state))

    def output(self):
        """Return the displacement (m) the present operator state gives."""
        return float(np.dot(self.weights, self.state))

    def operator_matrix(self, u):
        """
        Return the ``(N, n)`` play-operator outputs for ``u`` from rest (V).

        The PI output is linear in the weights: ``y = operator_matrix(u) @ weights``.
        """
        return play_operators(u, self.thresholds)[0]

    def loading_curve(self, u):
        """Return the initial loading curve ``sum w_i max(u - r_i, 0)`` (m) for u >= 0."""
        u = np.asarray(u, dtype=float)
        return np.maximum(u[..., None] - self.thresholds, 0.0) @ self.weights

    def inverse(self):
        """
        Return the exact inverse PI model ``y (m) -> u (V)``, with matching state.

        Weights ``w'_1 = 1/w_1``, ``w'_i = -w_i / (S_i S_{i-1})`` with partial sums
        ``S_i = w_1 + ... + w_i``; thresholds ``r'_i = sum_{j<=i} w_j (r_i - r_j)`` (m);
        initial states ``p'_i = sum_{j<=i} w_j p_i + sum_{j>i} w_j p_j`` (m).
        """
        bad = first_bad_partial_sum(self.weights)
        if bad is not None:
            raise NotInvertibleError('not invertible: partial sum of weights 1..%d <= 0'
                                     % (bad + 1))
        w, r, p = self.weights, self.thresholds, self.state
        S = np.cumsum(w)
        wi = np.empty_like(w)
        wi[0] = 1.0 / w[0]
        wi[1:] = -w[1:] / (S[1:] * S[:-1])
        ri = np.array([np.sum(w[:i + 1] * (r[i] - r[:i + 1])) for i in range(w.size)])
        tail = np.concatenate([np.cumsum((w * p)[::-1])[::-1][1:], [0.0]])
        pi = S * p + tail
        return InversePIModel(ri, wi, pi)

    def to_params(self):
        """Return the model as a ROS parameter mapping (SI units)."""
        return {'thresholds_v': [float(x) for x in self.thresholds],
                'weights_m_per_v': [float(x) for x in self.weights]}

    def save(self, path, node='hysteresis_compensator', extra=None, header=''):
        """
        Write the model as a ROS params file (the compensator loads this).

        :param extra: more parameters written before the model (e.g. ``model_source``).
        :param header: comment lines put first (see :func:`fiber_align.config.write_params`).
        """
        params = dict(extra or {})
        params.update(self.to_params())
        write_params(path, node, params, header)

    @classmethod
    def from_params(cls, params):
        """Build from a parameter mapping with ``thresholds_v`` and ``weights_m_per_v``."""
        try:
            return cls(params['thresholds_v'], params['weights_m_per_v'])
        except KeyError as exc:
            raise ConfigError('hysteresis model lacks %s (needs thresholds_v, '
                              'weights_m_per_v)' % exc) from None

    @classmethod
    def load(cls, path, node=None):
        """Load a model from a ROS params file (e.g. ``config/hysteresis_paper.yaml``)."""
        return cls.from_params(load_params(path, node))


class InversePIModel(_PlayModel):
    """
    The inverse of a :class:`PIModel`: displacement (m) -> voltage (V).

    Weighted play operators with thresholds in m and weights in V/m whose partial sums
    need not be positive; stepped like the model (:class:`_PlayModel`).
    """

    def __init__(self, thresholds_m, weights_v_per_m, state=None):
        """Build from thresholds (m), weights (V/m) and operator states (m)."""
        self.thresholds = np.asarray(thresholds_m, dtype=float).reshape(-1)
        self.weights = np.asarray(weights_v_per_m, dtype=float).reshape(-1)
        self.initial_state = (np.zeros_like(self.thresholds) if state is None
                              else np.asarray(state, dtype=float).reshape(-1))
        self._init_bank(self.initial_state)

    def reset(self, state=None):
        """Return to the initial state (or ``state``, m per operator)."""
        self._bank.reset(self._check_state(self.initial_state if state is None else state))


def paper_model():
    """Return the paper's Table 3 model (n = 10) from ``config/hysteresis_paper.yaml``."""
    return PIModel.load('hysteresis_paper.yaml')
