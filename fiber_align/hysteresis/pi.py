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

from dataclasses import dataclass

import numpy as np

from fiber_align.config import ConfigError, load_params, write_params


class NotInvertibleError(ValueError):
    """The weights have a non-positive partial sum; the model has no inverse."""


def play_operators(u, thresholds, state=None):
    """
    Run a bank of play operators over an input sequence.

    :param u: input sequence, shape ``(N,)``.
    :param thresholds: thresholds, shape ``(..., n)``; leading axes (e.g. a particle
        swarm) are vectorised over.
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
    lo_off = -r
    for k in range(u.size):
        uk = u[k]
        # max(u - r, min(u + r, y)) without temporaries beyond two in-place ops
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


@dataclass
class PIModel:
    """
    A Prandtl-Ishlinskii model ``u (V) -> y (m)``.

    :param thresholds: play thresholds in V, ``0 = r_1 < ... < r_n``.
    :param weights: operator weights in m/V.
    :param state: operator outputs (V) before the next sample; default at rest (zeros).
    :param require_invertible: refuse weights with a non-positive partial sum.
    """

    thresholds: np.ndarray
    weights: np.ndarray
    state: np.ndarray = None
    require_invertible: bool = True

    def __post_init__(self):
        self.thresholds = check_thresholds(self.thresholds)
        self.weights = np.asarray(self.weights, dtype=float).reshape(-1)
        if self.weights.shape != self.thresholds.shape:
            raise ValueError('%d weights for %d thresholds'
                             % (self.weights.size, self.thresholds.size))
        if not np.all(np.isfinite(self.weights)):
            raise ValueError('weights must be finite')
        if self.require_invertible:
            bad = first_bad_partial_sum(self.weights)
            if bad is not None:
                raise NotInvertibleError(
                    'not invertible: partial sum of weights 1..%d is %.6g <= 0; every '
                    'partial sum w_1 + ... + w_i must be > 0'
                    % (bad + 1, float(np.sum(self.weights[:bad + 1]))))
        if self.state is None:
            self.state = np.zeros_like(self.thresholds)
        else:
            self.state = np.asarray(self.state, dtype=float).reshape(self.thresholds.shape)
        self._r = self.thresholds.tolist()
        self._w = self.weights.tolist()
        self._s = self.state.tolist()

    @property
    def n(self):
        """Number of play operators."""
        return self.thresholds.size

    def reset(self, state=None):
        """Put the operators back at rest, or at ``state`` (V per operator)."""
        self.state = (np.zeros_like(self.thresholds) if state is None
                      else np.asarray(state, dtype=float).reshape(self.thresholds.shape))
        self._s = self.state.tolist()

    def output(self):
        """Return the present output (m) for the present operator state."""
        return float(np.dot(self.weights, np.asarray(self._s)))

    def step(self, u):
        """
        Advance one sample with input ``u`` (V); return the output (m).

        Pure-Python over the operators: for n of order ten this is several times
        faster than numpy on tiny arrays, and it is the per-control-period call.
        """
        s = self._s
        y = 0.0
        for i, r in enumerate(self._r):
            v = s[i]
            hi = u + r
            if v > hi:
                v = hi
            else:
                lo = u - r
                if v < lo:
                    v = lo
            s[i] = v
            y += self._w[i] * v
        return y

    def simulate(self, u, reset=True):
        """
        Run an input sequence (V) and return the output sequence (m).

        :param reset: start from rest (default) rather than from the present state.
        """
        if reset:
            self.reset()
        ops, final = play_operators(u, self.thresholds, np.asarray(self._s))
        self.state = final
        self._s = final.tolist()
        return ops @ self.weights

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
        w, r, p = self.weights, self.thresholds, np.asarray(self._s)
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

    def save(self, path, node='hysteresis_compensator', extra=None):
        """Write the model as a ROS params file (the compensator loads this)."""
        params = dict(extra or {})
        params.update(self.to_params())
        write_params(path, node, params)

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


class InversePIModel:
    """
    The inverse of a :class:`PIModel`: displacement (m) -> voltage (V).

    Structurally a PI model with thresholds in m and weights in V/m whose partial
    sums need not be positive, so it is kept as its own small class.
    """

    def __init__(self, thresholds_m, weights_v_per_m, state=None):
        """Build from thresholds (m), weights (V/m) and operator states (m)."""
        self.thresholds = np.asarray(thresholds_m, dtype=float).reshape(-1)
        self.weights = np.asarray(weights_v_per_m, dtype=float).reshape(-1)
        self.initial_state = (np.zeros_like(self.thresholds) if state is None
                              else np.asarray(state, dtype=float).reshape(-1))
        self._r = self.thresholds.tolist()
        self._w = self.weights.tolist()
        self._s = self.initial_state.tolist()

    def reset(self, state=None):
        """Return to the initial state (or ``state``, m per operator)."""
        st = self.initial_state if state is None else np.asarray(state, dtype=float)
        self._s = st.reshape(-1).tolist()

    @property
    def state(self):
        """Present operator states (m)."""
        return np.asarray(self._s)

    def step(self, y):
        """Advance one sample with desired displacement ``y`` (m); return voltage (V)."""
        s = self._s
        u = 0.0
        for i, r in enumerate(self._r):
            v = s[i]
            hi = y + r
            if v > hi:
                v = hi
            else:
                lo = y - r
                if v < lo:
                    v = lo
            s[i] = v
            u += self._w[i] * v
        return u

    def simulate(self, y, reset=True):
        """Run a displacement sequence (m) and return the voltage sequence (V)."""
        if reset:
            self.reset()
        ops, final = play_operators(y, self.thresholds, np.asarray(self._s))
        self._s = final.tolist()
        return ops @ self.weights


def paper_model():
    """Return the paper's Table 3 model (n = 10) from ``config/hysteresis_paper.yaml``."""
    return PIModel.load('hysteresis_paper.yaml')
