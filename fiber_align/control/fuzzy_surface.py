# SPDX-License-Identifier: Apache-2.0
"""
The fuzzy inference tabulated: the controller's per-period fast path, with an error bound.

:class:`FuzzySurface` interpolates the aggregated area and moment of a
:class:`fiber_align.control.fuzzy.FuzzyInference` (piecewise polynomials) on a grid
aligned with every place where they change formula; :func:`surface_error_bound` proves
how far its centroid can be from the exact one (below 1e-3 of each output's span for
the configured grid). Units: the fuzzy units of the inference (E, EC, increments).
"""

import numpy as np

from fiber_align.config import ConfigError


# --------------------------------------------------------------------------------------
# Precomputed surface
#
# Inside one rule cell (local coordinates s, t in [0, 1]) the four rule strengths are
# min(1 - s, 1 - t), min(1 - s, t), min(s, 1 - t), min(s, t). Every place where one of
# them, a clip level (a max of strengths), the overlap level min(a, b, 1/2) or the 1/2
# clip switches between linear pieces lies on the lines s = 1/2, t = 1/2, s = t or
# s = 1 - t. These cut the cell into 8 triangles; inside each, every clip level is one
# linear function of (s, t), so the aggregated area is a polynomial of degree 2 and the
# moment one of degree 3 (see FuzzyInference.area_moment). The surface samples area and
# moment (not the centroid) on a grid of q x q sub-cells per rule cell (q even) and
# splits every sub-cell into two triangles along the diagonal that lies on s = t or
# s = 1 - t where those lines cross it, so no piece boundary runs through a triangle.
# Linear interpolation of a C2 function on a right triangle with legs h errs by at most
# K h^2 / 4 (K: largest |eigenvalue| of the Hessian on the triangle; the sum of
# lambda_i |v_i - p|^2 is at most the squared circumradius h^2 / 2). The centroid
# u = M / A (about the domain centre, |u| <= 3 output spacings) then errs by at most
# (eps_M + |u|max eps_A) / (A_min - eps_A); A >= 3/8 everywhere (the strongest rule fires
# at >= 1/2 and its clipped set alone covers 3/8), and per piece A_min and |M|max follow
# from the exact values at its vertices and the same estimate on the whole piece.
# surface_error_bound() evaluates this with the Hessians of every piece (constant for A;
# affine for M, so its norm, a convex function, peaks at a vertex), which central
# differences give exactly for polynomials of degree <= 3.
# --------------------------------------------------------------------------------------

def _regions():
    """Return the 8 triangles (vertices in cell coordinates s, t) of a rule cell."""
    out = []
    for qs in (0, 1):
        for qt in (0, 1):
            x0, y0 = 0.5 * qs, 0.5 * qt
            a, b = (x0, y0), (x0 + 0.5, y0)
            c, d = (x0 + 0.5, y0 + 0.5), (x0, y0 + 0.5)
            out += [(a, b, c), (a, c, d)] if qs == qt else [(a, b, d), (b, c, d)]
    return out


def surface_error_bound(fis, intervals):
    """
    Return the proven bound of :class:`FuzzySurface` error, per output, over the span.

    See the comment block above :class:`FuzzySurface` for the argument.

    :param fis: the :class:`FuzzyInference`.
    :param intervals: sub-intervals ``q`` per rule cell and axis.
    :returns: numpy array of 3 (dkp, dki, dkd): the largest centroid error as a fraction
        of each output's span.
    """
    h = 1.0 / int(intervals)
    d = 1e-3      # difference step (cell units); the stencils stay inside each triangle
    bary = np.array([[0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6]])
    to_vertex = np.linalg.inv(bary)   # Hessian at the vertices from the 3 inner points
    stencil = [(0, 0), (d, 0), (-d, 0), (0, d), (0, -d), (d, d), (d, -d), (-d, d), (-d, -d)]
    pts = []
    for i in range(6):
        for j in range(6):
            for tri in _regions():
                for p in bary @ np.array(tri):
                    for ds, dt in stencil:
                        pts.append((i + p[0] + ds, j + p[1] + dt))
    pts = np.array(pts)
    e = fis.e_domain[0] + pts[:, 0] * fis._e[1]
    ec = fis.ec_domain[0] + pts[:, 1] * fis._ec[1]
    am = fis.area_moment_grid(e, ec).reshape(3, 2, -1, 3, 9)   # piece, inner pt, stencil
    f0, fsp, fsm, ftp, ftm = (am[..., k] for k in range(5))
    hss = (fsp - 2 * f0 + fsm) / d ** 2
    htt = (ftp - 2 * f0 + ftm) / d ** 2
    hst = (am[..., 5] - am[..., 6] - am[..., 7] + am[..., 8]) / (4 * d * d)
    # affine extrapolation to the vertices, then the spectral norm of [[hss, hst], ...]
    hv = [np.einsum('vl,...l->...v', to_vertex, x) for x in (hss, htt, hst)]
    mean = 0.5 * (hv[0] + hv[1])
    rad = np.sqrt((0.5 * (hv[0] - hv[1])) ** 2 + hv[2] ** 2)
    k = np.max(np.abs(mean) + rad, axis=-1)        # (3 outputs, 2 quantities, pieces)
    # per piece: a lower bound of A and an upper bound of |M| from the exact values at
    # its vertices and the same interpolation estimate on the whole piece (legs 1/2,
    # squared circumradius 1/8); |u| = |M| / A <= 3 in any case
    verts = np.array([(i + v[0], j + v[1]) for i in range(6) for j in range(6)
                      for tri in _regions() for v in tri])
    av = fis.area_moment_grid(fis.e_domain[0] + verts[:, 0] * fis._e[1],
                              fis.ec_domain[0] + verts[:, 1] * fis._ec[1]).reshape(3, 2, -1, 3)
    a_min = np.maximum(np.min(av[:, 0], axis=-1) - k[:, 0] / 16.0, 0.375)
    m_max = np.max(np.abs(av[:, 1]), axis=-1) + k[:, 1] / 16.0
    u_max = np.minimum(m_max / a_min, 3.0)
    eps_a = k[:, 0] * h * h / 4.0
    eps_m = k[:, 1] * h * h / 4.0
    du = (eps_m + u_max * eps_a) / (a_min - eps_a)
    return np.max(du, axis=-1) / 6.0


class FuzzySurface:
    """
    The fuzzy inference from precomputed tables of aggregated area and moment.

    :meth:`evaluate` matches :meth:`FuzzyInference.evaluate` within
    :func:`surface_error_bound` (about 7.2e-4 of each output's span for q = 48 with the
    paper's rule base) at a fraction of the cost; building the tables takes about 0.1 s
    (vectorised), so a caller that builds controllers repeatedly passes one surface down
    (:meth:`matches`).

    :param fis: the :class:`FuzzyInference` to tabulate.
    :param intervals: ``q``, sub-intervals per rule cell and axis (even, >= 2).
    """

    def __init__(self, fis, intervals):
        """Sample area and moment on the grid (see the comment block above)."""
        q = int(intervals)
        if q < 2 or q % 2:
            raise ConfigError('surface intervals must be an even number >= 2, got %r'
                              % (intervals,))
        self.fis = fis
        self.q = q
        n = 6 * q + 1
        self.n = n
        ge = np.linspace(fis.e_domain[0], fis.e_domain[1], n)
        gc = np.linspace(fis.ec_domain[0], fis.ec_domain[1], n)
        e, ec = np.meshgrid(ge, gc, indexing='ij')
        am = fis.area_moment_grid(e, ec)                      # (3, 2, n, n)
        flat = np.moveaxis(am.reshape(6, n, n), 0, -1).reshape(-1, 6)
        self.nodes = [tuple(row) for row in flat.tolist()]   # index a * n + b
        self._e0 = fis.e_domain[0]
        self._ec0 = fis.ec_domain[0]
        self._einv = (n - 1) / (fis.e_domain[1] - fis.e_domain[0])
        self._ecinv = (n - 1) / (fis.ec_domain[1] - fis.ec_domain[0])
        self._top = float(n - 1)
        self._out = list(fis._out)

    def matches(self, fis, intervals):
        """Return whether this surface tabulates ``fis`` with ``intervals`` (reusable)."""
        return self.q == int(intervals) and self.fis.key() == fis.key()

    def area_moment(self, e, ec):
        """Return ``(A0, M0, A1, M1, A2, M2)`` interpolated at E, EC (fuzzy units)."""
        x = (e - self._e0) * self._einv
        y = (ec - self._ec0) * self._ecinv
        top = self._top
        if x <= 0.0:
            x = 0.0
        elif x >= top:
            x = top
        if y <= 0.0:
            y = 0.0
        elif y >= top:
            y = top
        i = int(x)
        j = int(y)
        n = self.n
        if i >= n - 1:
            i = n - 2
        if j >= n - 1:
            j = n - 2
        fx = x - i
        fy = y - j
        q = self.q
        nodes = self.nodes
        base = i * n + j
        if (i % q + j % q) == q - 1:      # split along s = 1 - t
            if fx + fy <= 1.0:
                wa, wb, wc = 1.0 - fx - fy, fx, fy
                za, zb, zc = nodes[base], nodes[base + n], nodes[base + 1]
            else:
                wa, wb, wc = fx + fy - 1.0, 1.0 - fy, 1.0 - fx
                za, zb, zc = nodes[base + n + 1], nodes[base + n], nodes[base + 1]
        elif fx >= fy:                    # split along s = t, lower triangle
            wa, wb, wc = 1.0 - fx, fx - fy, fy
            za, zb, zc = nodes[base], nodes[base + n], nodes[base + n + 1]
        else:
            wa, wb, wc = 1.0 - fy, fy - fx, fx
            za, zb, zc = nodes[base], nodes[base + 1], nodes[base + n + 1]
        a0, a1, a2, a3, a4, a5 = za
        b0, b1, b2, b3, b4, b5 = zb
        c0, c1, c2, c3, c4, c5 = zc
        return (wa * a0 + wb * b0 + wc * c0, wa * a1 + wb * b1 + wc * c1,
                wa * a2 + wb * b2 + wc * c2, wa * a3 + wb * b3 + wc * c3,
                wa * a4 + wb * b4 + wc * c4, wa * a5 + wb * b5 + wc * c5)

    def gains(self, e, ec, g):
        """
        Return ``(g0 + g1 M0/A0, g2 + g3 M1/A1, g4 + g5 M2/A2)`` for E, EC (fuzzy units).

        The centroids of :meth:`area_moment` mapped affinely to gains (the controller's
        fast path): ``g`` maps each centroid (about the domain centre, in output
        spacings) to its gain (:class:`fiber_align.control.fuzzy_pid.FuzzyPid`).
        """
        a0, m0, a1, m1, a2, m2 = self.area_moment(e, ec)
        g0, g1, g2, g3, g4, g5 = g
        return g0 + g1 * (m0 / a0), g2 + g3 * (m1 / a1), g4 + g5 * (m2 / a2)

    def evaluate(self, e, ec):
        """Return ``(dkp, dki, dkd)`` (fuzzy units) for E, EC (fuzzy units)."""
        if e != e or ec != ec:
            raise ValueError('fuzzy inference got a NaN input')
        a0, m0, a1, m1, a2, m2 = self.area_moment(e, ec)
        (l0, h0), (l1, h1), (l2, h2) = self._out
        return (l0 + h0 * (3.0 + m0 / a0), l1 + h1 * (3.0 + m1 / a1),
                l2 + h2 * (3.0 + m2 / a2))
