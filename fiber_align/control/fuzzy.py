# SPDX-License-Identifier: Apache-2.0
"""
Mamdani fuzzy inference of the paper's fuzzy PID (SEED-NOTES section 6), exact and fast.

Inputs ``E`` and ``EC`` and the three outputs each have seven triangular sets NB..PB whose
peaks are evenly spaced over the variable's domain, each falling to zero at its
neighbours' peaks (the end sets are half triangles inside the domain). Inputs beyond a
domain are clamped to it. Rule strength is ``min``, aggregation ``max``, defuzzification
the centre of gravity of the aggregated set over the output's domain.

:meth:`FuzzyInference.evaluate` computes the centre of gravity in closed form. Between
two neighbouring output peaks only the two sets peaking there are non-zero, so with clip
levels ``a`` (left set) and ``b`` (right set) and the local coordinate ``s`` in [0, 1]::

    max(min(a, 1 - s), min(b, s)) = min(a, 1 - s) + min(b, s) - min(a, b, s, 1 - s)

and each of the three terms is a clipped triangle with a polynomial area and moment.
The result is the exact centroid of the continuous aggregated set (up to rounding);
:func:`reference_mamdani` is the textbook computation on a sampled universe that the
tests compare it with.

:class:`fiber_align.control.fuzzy_surface.FuzzySurface` is the per-period fast path of the
controller: it interpolates the aggregated area and moment (piecewise polynomials) on a
grid aligned with every place where they change formula, with a proven error bound.

Units: everything here is in the paper's fuzzy units (E, EC and the gain increments are
dimensionless numbers on their domains); :class:`fiber_align.control.fuzzy_pid.FuzzyPid`
converts SI errors to them with its input scale factors.
"""

import numpy as np

from fiber_align.config import ConfigError

LABELS = ('NB', 'NM', 'NS', 'ZO', 'PS', 'PM', 'PB')
# the paper's pinyin initials, in the same order
PINYIN = ('FD', 'FZ', 'FX', 'Z', 'ZX', 'ZZ', 'ZD')
OUTPUTS = ('dkp', 'dki', 'dkd')


def parse_rule_table(rows, name='rules'):
    """
    Parse seven rows of seven labels (rows E = NB..PB, columns EC = NB..PB) to indices.

    :param rows: seven strings like ``'PB PB PM PM PS ZO ZO'`` or seven lists of labels;
        pinyin initials (FD .. ZD) are accepted too.
    :returns: a 7 x 7 list of set indices 0..6.
    """
    lookup = {lab: i for i, lab in enumerate(LABELS)}
    lookup.update({lab: i for i, lab in enumerate(PINYIN)})
    if len(rows) != 7:
        raise ConfigError('%s must have 7 rows (E = NB..PB), got %d' % (name, len(rows)))
    table = []
    for r, row in enumerate(rows):
        cells = row.split() if isinstance(row, str) else list(row)
        if len(cells) != 7:
            raise ConfigError('%s row %d must have 7 labels, got %d' % (name, r + 1, len(cells)))
        try:
            table.append([lookup[str(c).upper()] for c in cells])
        except KeyError as exc:
            raise ConfigError('%s row %d: unknown label %s (allowed: %s)'
                              % (name, r + 1, exc, ' '.join(LABELS))) from None
    return table


def _check_domain(dom, name):
    """Return ``(lo, hi)`` floats of a domain, checking lo < hi."""
    try:
        lo, hi = float(dom[0]), float(dom[1])
    except (TypeError, ValueError, IndexError):
        raise ConfigError('%s must be [lo, hi], got %r' % (name, dom)) from None
    if not hi > lo:
        raise ConfigError('%s must have lo < hi, got %r' % (name, dom))
    return lo, hi


def _aggregate(c, minimum, zero, sets=range(7)):
    """
    Return ``(A, M)`` of the aggregated output set from its clip levels (the one formula).

    :param c: clip levels of the 7 sets NB..PB and a trailing 0 (floats, or arrays of one
        shape for a grid), fuzzy units.
    :param minimum: ``min`` for floats, ``numpy.minimum`` for arrays.
    :param zero: the starting sum (0.0, or an array of zeros).
    :param sets: the sets to add; a set clipped at 0 adds exactly 0 to both sums (its
        overlap term too), so the scalar path passes only the fired ones.
    :returns: area and first moment about the domain centre, in output peak spacings (see
        :meth:`FuzzyInference.area_moment`).
    """
    area = zero
    mom = zero
    for k in sets:
        a = c[k]
        ha = a - 0.5 * a * a
        ma = 0.5 * a - 0.5 * a * a + a * a * a / 6.0
        if k == 0:
            area = area + ha
            mom = mom + (-3.0 * ha + ma)
        elif k == 6:
            area = area + ha
            mom = mom + (3.0 * ha - ma)
        else:
            area = area + 2.0 * ha
            mom = mom + 2.0 * (k - 3) * ha
        m = minimum(minimum(a, c[k + 1]), 0.5)
        am = m - m * m
        area = area - am
        mom = mom - (k - 2.5) * am
    return area, mom


class FuzzyInference:
    """
    Two-input, three-output Mamdani system with seven evenly spaced triangles per variable.

    :param e_domain: ``(lo, hi)`` of E (fuzzy units).
    :param ec_domain: ``(lo, hi)`` of EC (fuzzy units).
    :param out_domains: three ``(lo, hi)`` of dkp, dki, dkd (fuzzy units).
    :param rules: three 7 x 7 tables (rows E, columns EC) of labels or set indices.
    """

    def __init__(self, e_domain, ec_domain, out_domains, rules):
        """Check and store the rule base."""
        self.e_domain = _check_domain(e_domain, 'e_domain')
        self.ec_domain = _check_domain(ec_domain, 'ec_domain')
        if len(out_domains) != 3 or len(rules) != 3:
            raise ConfigError('need 3 output domains and 3 rule tables (dkp, dki, dkd)')
        self.out_domains = [_check_domain(d, '%s_domain' % n)
                            for d, n in zip(out_domains, OUTPUTS)]
        tabs = []
        for tab, n in zip(rules, OUTPUTS):
            if tab and isinstance(tab[0], str) or (tab and isinstance(tab[0][0], str)):
                tabs.append(parse_rule_table(tab, 'rules_' + n))
            else:
                t = [[int(x) for x in row] for row in tab]
                if len(t) != 7 or any(len(row) != 7 or min(row) < 0 or max(row) > 6
                                      for row in t):
                    raise ConfigError('rules_%s must be 7 x 7 indices 0..6' % n)
                tabs.append(t)
        self.rules = tabs
        # per cell the three output set indices, for the fast path
        self._cell = [[tuple(tabs[o][i][j] for o in range(3)) for j in range(7)]
                      for i in range(7)]
        self._e = (self.e_domain[0], (self.e_domain[1] - self.e_domain[0]) / 6.0)
        self._ec = (self.ec_domain[0], (self.ec_domain[1] - self.ec_domain[0]) / 6.0)
        self._out = [(lo, (hi - lo) / 6.0) for lo, hi in self.out_domains]

    @classmethod
    def from_params(cls, p):
        """Build from the ``fuzzy`` mapping of ``config/controller.yaml``."""
        try:
            return cls(p['e_domain'], p['ec_domain'],
                       [p['dkp_domain'], p['dki_domain'], p['dkd_domain']],
                       [p['rules_dkp'], p['rules_dki'], p['rules_dkd']])
        except KeyError as exc:
            raise ConfigError('fuzzy parameters lack %s' % exc) from None

    @staticmethod
    def _fuzzify(x, lo_h, hi):
        """Return ``(i, s)``: x lies between peaks i and i + 1 at fraction s in [0, 1]."""
        lo, h = lo_h
        if x <= lo:
            return 0, 0.0
        if x >= hi:
            return 5, 1.0
        p = (x - lo) / h
        i = int(p)
        if i > 5:
            i = 5
        return i, p - i

    def area_moment(self, e, ec):
        """
        Return ``((A, M), (A, M), (A, M))`` of the aggregated sets of dkp, dki, dkd.

        ``A`` is the area and ``M`` the first moment about the centre of the output
        domain of the aggregated (max of clipped) set, both with the output's peak
        spacing as the unit of length; the centroid is ``centre + spacing * M / A``.
        Computed in closed form set by set: a set ``k`` clipped at ``c`` adds
        ``n_k (c - c^2 / 2)`` to ``A`` (``n_k`` = 2 half triangles, 1 at a domain end)
        and ``(k - 3) n_k (c - c^2 / 2) + d_k (c / 2 - c^2 / 2 + c^3 / 6)`` to ``M``
        (``d_k`` = +1 at the lower end, -1 at the upper end, else 0), and each pair of
        neighbouring fired sets with ``m = min(a, b, 1/2)`` removes the part counted
        twice, ``m - m^2`` (moment ``(k + 1/2 - 3) (m - m^2)``).
        """
        if e != e or ec != ec:
            raise ValueError('fuzzy inference got a NaN input')
        i, s = self._fuzzify(e, self._e, self.e_domain[1])
        j, t = self._fuzzify(ec, self._ec, self.ec_domain[1])
        mi0, mi1 = 1.0 - s, s
        mj0, mj1 = 1.0 - t, t
        cell = self._cell
        fired = ((mi0 if mi0 < mj0 else mj0, cell[i][j]),
                 (mi0 if mi0 < mj1 else mj1, cell[i][j + 1]),
                 (mi1 if mi1 < mj0 else mj0, cell[i + 1][j]),
                 (mi1 if mi1 < mj1 else mj1, cell[i + 1][j + 1]))
        out = []
        for o in range(3):
            c = [0.0] * 8
            for w, ks in fired:
                k = ks[o]
                if w > c[k]:
                    c[k] = w
            out.append(_aggregate(c, min, 0.0, [k for k in range(7) if c[k] != 0.0]))
        return out[0], out[1], out[2]

    def evaluate(self, e, ec):
        """
        Return ``(dkp, dki, dkd)`` (fuzzy units) for inputs E and EC (fuzzy units).

        The exact centre of gravity (see :meth:`area_moment`). NaN inputs raise
        ValueError (the caller decides how to hold).
        """
        am = self.area_moment(e, ec)
        return tuple(lo + h * (3.0 + mo / ar) for (ar, mo), (lo, h) in zip(am, self._out))

    def area_moment_grid(self, e, ec):
        """
        Return :meth:`area_moment` on arrays: shape ``(3, 2) + shape`` (vectorised).

        :param e: E values (fuzzy units), array.
        :param ec: EC values (fuzzy units), array of the same shape.
        """
        e = np.clip(np.asarray(e, dtype=float), *self.e_domain)
        ec = np.clip(np.asarray(ec, dtype=float), *self.ec_domain)
        pe = (e - self._e[0]) / self._e[1]
        pc = (ec - self._ec[0]) / self._ec[1]
        i = np.minimum(pe.astype(int), 5)
        j = np.minimum(pc.astype(int), 5)
        s = pe - i
        t = pc - j
        w = [np.minimum(1.0 - s, 1.0 - t), np.minimum(1.0 - s, t),
             np.minimum(s, 1.0 - t), np.minimum(s, t)]
        idx = [(i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)]
        out = np.empty((3, 2) + e.shape)
        for o in range(3):
            tab = np.asarray(self.rules[o])
            c = np.zeros((8,) + e.shape)
            for wr, (a, b) in zip(w, idx):
                k = tab[a, b]
                for kk in range(7):
                    sel = k == kk
                    c[kk] = np.where(sel, np.maximum(c[kk], wr), c[kk])
            area, mom = _aggregate(c, np.minimum, np.zeros(e.shape))
            out[o, 0] = area
            out[o, 1] = mom
        return out

    def surface(self, n):
        """
        Return ``(e, ec, outputs)`` on an n x n grid over the input domains.

        :returns: ``e`` and ``ec`` of shape ``(n, n)`` (``e`` varies along axis 0) and
            ``outputs`` of shape ``(3, n, n)`` (dkp, dki, dkd; fuzzy units, before the
            output scale factors).
        """
        n = int(n)
        if n < 2:
            raise ValueError('need at least 2 points per axis, got %d' % n)
        ge = np.linspace(self.e_domain[0], self.e_domain[1], n)
        gc = np.linspace(self.ec_domain[0], self.ec_domain[1], n)
        e, ec = np.meshgrid(ge, gc, indexing='ij')
        am = self.area_moment_grid(e, ec)
        out = np.empty((3, n, n))
        for o, (lo, h) in enumerate(self._out):
            out[o] = lo + h * (3.0 + am[o, 1] / am[o, 0])
        return e, ec, out

    def key(self):
        """Return a hashable description of the rule base (domains and tables)."""
        return (self.e_domain, self.ec_domain, tuple(self.out_domains),
                tuple(tuple(tuple(row) for row in tab) for tab in self.rules))


def triangles(x, lo, hi):
    """
    Return the 7 memberships of ``x`` (array) for evenly spaced triangles on [lo, hi].

    :returns: array of shape ``(7,) + x.shape``.
    """
    x = np.clip(np.asarray(x, dtype=float), lo, hi)
    h = (hi - lo) / 6.0
    peaks = lo + h * np.arange(7)
    return np.maximum(0.0, 1.0 - np.abs(x[None, ...] - peaks.reshape((7,) + (1,) * x.ndim)) / h)


def reference_mamdani(fis, e, ec, n_points=10001):
    """
    Return ``(dkp, dki, dkd)`` by textbook Mamdani on a sampled output universe.

    Fuzzify with the triangles, fire all 49 rules with ``min``, clip each output set,
    aggregate with ``max`` over an ``n_points`` universe spanning the output domain, and
    take the discrete centre of gravity. Slow and obvious; used to check
    :meth:`FuzzyInference.evaluate`.
    """
    mu_e = triangles(e, *fis.e_domain)
    mu_c = triangles(ec, *fis.ec_domain)
    w = np.minimum(mu_e[:, None], mu_c[None, :])  # 7 x 7 rule strengths
    res = []
    for o, (lo, hi) in enumerate(fis.out_domains):
        x = np.linspace(lo, hi, int(n_points))
        sets = triangles(x, lo, hi)  # 7 x N
        clip = np.zeros(7)
        tab = np.asarray(fis.rules[o])
        for k in range(7):
            sel = tab == k
            if sel.any():
                clip[k] = w[sel].max()
        mu = np.max(np.minimum(clip[:, None], sets), axis=0)
        res.append(float(np.sum(x * mu) / np.sum(mu)))
    return tuple(res)
