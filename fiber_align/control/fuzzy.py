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


def _clipped_area(a):
    """Area of ``min(a, 1 - s)`` on s in [0, 1] (a clipped half triangle)."""
    return a - 0.5 * a * a


def _clipped_moment(a):
    """First moment about s = 0 of ``min(a, 1 - s)`` on s in [0, 1]."""
    return 0.5 * a * (1.0 - a) ** 2 + 0.5 * a * a - a * a * a / 3.0


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

    def evaluate(self, e, ec):
        """
        Return ``(dkp, dki, dkd)`` (fuzzy units) for inputs E and EC (fuzzy units).

        NaN inputs raise ValueError (the caller decides how to hold).
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
            c = [0.0] * 7
            for w, ks in fired:
                k = ks[o]
                if w > c[k]:
                    c[k] = w
            area = 0.0
            mom = 0.0
            for k in range(6):
                a = c[k]
                b = c[k + 1]
                if a == 0.0 and b == 0.0:
                    continue
                m = a if a < b else b
                if m > 0.5:
                    m = 0.5
                amin = m - m * m
                aa = a - 0.5 * a * a
                ab = b - 0.5 * b * b
                ar = aa + ab - amin
                mo = (0.5 * a * (1.0 - a) ** 2 + 0.5 * a * a - a * a * a / 3.0
                      + ab - (0.5 * b * (1.0 - b) ** 2 + 0.5 * b * b - b * b * b / 3.0)
                      - 0.5 * amin)
                area += ar
                mom += mo + k * ar
            lo, h = self._out[o]
            out.append(lo + h * mom / area)
        return out[0], out[1], out[2]

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
        out = np.empty((3, n, n))
        for a in range(n):
            for b in range(n):
                out[:, a, b] = self.evaluate(ge[a], gc[b])
        return e, ec, out


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
