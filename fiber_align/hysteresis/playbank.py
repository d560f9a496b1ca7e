# SPDX-License-Identifier: Apache-2.0
"""
Fast exact stepping of a Prandtl-Ishlinskii operator bank (pure Python, per sample).

A PI model (or its inverse) is ``Y = sum_i w_i s_i`` over play operators
``s_i <- max(u - r_i, min(u + r_i, s_i))`` with thresholds ``0 <= r_1 < ... < r_n``.
Stepping all ``n`` operators every control period costs ``O(n)`` Python operations
(50 for the plant's dense truth model). :class:`PlayBank` gives the same outputs in
amortised ``O(1)``:

* the operator states form a memory curve with ``s_i + r_i`` non-decreasing and
  ``s_i - r_i`` non-increasing in ``i`` (true at rest and kept by every step), so when
  the input rises the operators it drags are a prefix ``i < m`` (``s_i = u - r_i``),
  and likewise when it falls (``s_i = u + r_i``);
* the prefix is kept lazily: ``Y = W_m u - dir R_m + T`` with the prefix sums
  ``W_m = sum_{i<m} w_i``, ``R_m = sum_{i<m} w_i r_i`` and the tail
  ``T = sum_{i>=m} w_i s_i`` of the operators that did not move;
* a step only visits the operators that join the prefix, and a reversal only writes
  back the states of the operators that leave it.

Units follow the model: for the forward model ``u`` and ``r`` in V, ``w`` in m/V and
``Y`` in m; for the inverse ``u`` and ``r`` in m, ``w`` in V/m and ``Y`` in V. The
result equals the operator-by-operator sum up to rounding (a few ulp of the output;
``test_control_fast.py``); it is deterministic, so the offline simulation and the ROS
nodes, which both use this class, agree bit for bit.
"""


class PlayBank:
    """
    A bank of play operators with weights, stepped in amortised constant time.

    :param thresholds: operator thresholds, non-negative and strictly increasing.
    :param weights: operator weights (any sign).
    :param state: operator states before the first step (default 0: at rest).
    :raises ValueError: bad thresholds, or a state that is not a memory curve.
    """

    def __init__(self, thresholds, weights, state=None):
        """Check the parameters, precompute the prefix sums and set the state."""
        r = [float(x) for x in thresholds]
        w = [float(x) for x in weights]
        if not r or len(r) != len(w):
            raise ValueError('need as many weights as thresholds (>= 1)')
        if r[0] < 0 or any(b <= a for a, b in zip(r, r[1:])):
            raise ValueError('thresholds must be >= 0 and strictly increasing')
        self._r = r
        self._w = w
        self.n = len(r)
        wsum = [0.0]
        rsum = [0.0]
        for ri, wi in zip(r, w):
            wsum.append(wsum[-1] + wi)
            rsum.append(rsum[-1] + wi * ri)
        self._wsum = wsum
        self._rsum = rsum
        self.initial = [0.0] * self.n if state is None else [float(x) for x in state]
        self.reset()

    @classmethod
    def from_model(cls, model):
        """Return a bank of a :class:`~fiber_align.hysteresis.pi.PIModel` or its inverse."""
        return cls(model.thresholds, model.weights, list(model.state))

    def reset(self, state=None):
        """Put the operators at ``state`` (default: the initial state); no prefix moves."""
        s = list(self.initial if state is None else [float(x) for x in state])
        if len(s) != self.n:
            raise ValueError('state needs %d values, got %d' % (self.n, len(s)))
        r = self._r
        # A state computed in floating point (a model's inverse, play_operators) meets the
        # memory-curve inequalities only to rounding: allow that much, relative to its size.
        tol = 1e-12 * max(max(abs(x) for x in s), r[-1])
        for i in range(1, self.n):
            if s[i] + r[i] < s[i - 1] + r[i - 1] - tol or \
                    s[i] - r[i] > s[i - 1] - r[i - 1] + tol:
                raise ValueError('state is not a play-operator memory curve at operator %d'
                                 % i)
        self._s = s
        self._m = 0
        self._dir = 0
        self._u = 0.0
        self._tail = sum(wi * si for wi, si in zip(self._w, s))
        self.y = self._tail
        self._set_fast()

    def _set_fast(self):
        """Cache what the fast path of :meth:`step` needs for the present prefix."""
        m = self._m
        d = self._dir
        self._wm = self._wsum[m]
        self._rm = self._rsum[m] * d      # y = wm u - rm + tail while moving in d
        # the next operator joins the prefix when u passes this (inf: none left)
        if m < self.n and d:
            self._next = self._s[m] + d * self._r[m]
        else:
            self._next = float('inf') * (d if d else 1)

    @property
    def state(self):
        """Return the operator states (a new list, same unit as the input)."""
        s = list(self._s)
        u, d, r = self._u, self._dir, self._r
        for i in range(self._m):
            s[i] = u - d * r[i]
        return s

    def step(self, u):
        """Advance one sample with input ``u``; return the bank output."""
        d = self._dir
        # fast path: moving on in the same direction without reaching the next operator
        if d > 0:
            if self._u <= u <= self._next:
                self._u = u
                y = self.y = self._wm * u - self._rm + self._tail
                return y
        elif d < 0:
            if self._next <= u <= self._u:
                self._u = u
                y = self.y = self._wm * u - self._rm + self._tail
                return y
        return self._step(u)

    def _step(self, u):
        """Advance one sample in the general case (see the module docstring)."""
        m = self._m
        s = self._s
        r = self._r
        w = self._w
        tail = self._tail
        n = self.n
        if m:
            d = self._dir
            ul = self._u
            scan = True
            if (d > 0 and u < ul) or (d < 0 and u > ul):
                # reversal: the prefix operators that do not follow the new direction
                # keep their last lazy state ul - d r_i; write those back
                i = 0
                if d > 0:
                    while i < m and ul - r[i] > u + r[i]:
                        i += 1
                else:
                    while i < m and ul + r[i] < u - r[i]:
                        i += 1
                k = i
                while i < m:
                    si = ul - d * r[i]
                    s[i] = si
                    tail += w[i] * si
                    i += 1
                # only a prefix that turned whole can absorb further operators
                scan = k == m
                m = k
                d = -d
        if not m:
            scan = True
            if s[0] < u - r[0]:
                d = 1
            elif s[0] > u + r[0]:
                d = -1
            else:
                d = 0
                scan = False
        if scan:
            # extend the prefix over the operators the input now drives in direction d
            if d > 0:
                while m < n and s[m] < u - r[m]:
                    tail -= w[m] * s[m]
                    m += 1
            else:
                while m < n and s[m] > u + r[m]:
                    tail -= w[m] * s[m]
                    m += 1
        self._m = m
        self._dir = d
        self._u = u
        self._tail = tail
        self._set_fast()
        y = self.y = self._wm * u - self._rm + tail
        return y
