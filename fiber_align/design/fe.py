# SPDX-License-Identifier: Apache-2.0
"""
Euler-Bernoulli beam finite elements of the tapered laminate with its extension.

The beam is clamped at ``x = 0``. ``n_piezo`` elements cover the piezo part ``[0, L]``
(laminate: bending stiffness ``EI = b(x) D12 / 12``, mass per length
``b(x) (2 rho_p hp + rho_b hb)``, width ``b`` linear from A to B) and ``n_ext`` elements
cover the extension ``[L, L0]`` (metal alone: ``EI = B Eb hb^3 / 12``, mass per length
``B rho_b hb``). An optional point mass sits at ``x = L0``.

Elements are two-node cubic Hermite elements (deflection and slope at each node). Element
matrices are integrated by 4-point Gauss quadrature, which is exact for the linear width
(stiffness: cubic integrand; mass: degree 7). The piezo actuation enters as the
eigen-curvature load ``f = int N''^T M_p(x) dx`` with the actuation moment
``M_p(x) = b(x) Ep |d31| V (hb + hp)``; because ``M_p / EI`` is constant on the piezo part,
the exact free deflection is the quadratic of equation 3 plus a straight extension, which
these elements represent exactly.

Everything is batched: every geometry argument may be an array of shape ``(N,)`` and the
matrices have shape ``(N, n, n)``, so a sweep of many geometries is one set of array
operations. SI units throughout.
"""

import numpy as np

from fiber_align.design.model import d12

_GX, _GW = np.polynomial.legendre.leggauss(4)
_GX = 0.5 * (_GX + 1.0)         # points on [0, 1]
_GW = 0.5 * _GW


def _shape(xi, le):
    """
    Return Hermite shape functions N and second x-derivatives N'' at xi (le in m).

    :returns: arrays of shape ``le.shape + (4,)``.
    """
    n = np.stack(np.broadcast_arrays(1 - 3 * xi**2 + 2 * xi**3, le * (xi - 2 * xi**2 + xi**3),
                                     3 * xi**2 - 2 * xi**3, le * (-xi**2 + xi**3)), axis=-1)
    b = np.stack(np.broadcast_arrays(-6 + 12 * xi, le * (-4 + 6 * xi), 6 - 12 * xi,
                                     le * (-2 + 6 * xi)), axis=-1) / (le**2)[..., None]
    return n, b


def split_elements(n_elements, L, L0):  # noqa: N803
    """
    Return ``(n_piezo, n_ext)``: elements on the piezo part and on the extension.

    The extension gets a share proportional to its length (at least one element when
    ``L0 > L``, none when ``L0 == L``); the rest go to the piezo part (at least 2).
    """
    L = np.atleast_1d(np.asarray(L, dtype=float))
    L0 = np.atleast_1d(np.asarray(L0, dtype=float))
    frac = np.max((L0 - L) / L0)
    if frac <= 0:
        return int(n_elements), 0
    n_ext = min(max(1, int(round(n_elements * frac))), int(n_elements) - 2)
    return int(n_elements) - n_ext, n_ext


def assemble(A, B, L, L0, hp, hb, Ep, Eb, d31, rho_p, rho_b, tip_mass=0.0,  # noqa: N803
             n_elements=40):
    """
    Assemble the clamped stiffness, mass and unit-voltage load of a batch of beams.

    All geometry and material arguments are SI scalars or arrays of one shape ``(N,)``
    (or scalars); a batch must be all with extension (``L0 > L``) or all without.

    :returns: dict with ``K`` (N/m, shape ``(N, n, n)``), ``M`` (kg), ``f`` (load per volt,
        N/V, shape ``(N, n)``), ``x`` (node positions, m, shape ``(N, nodes)``) and
        ``tip`` (index of the deflection dof at x = L0 in the reduced system).
    """
    args = np.broadcast_arrays(*[np.atleast_1d(np.asarray(a, dtype=float)) for a in
                                 (A, B, L, L0, hp, hb, Ep, Eb, d31, rho_p, rho_b, tip_mass)])
    A, B, L, L0, hp, hb, Ep, Eb, d31, rho_p, rho_b, tip_mass = args
    nb = A.shape[0]
    ext = L0 - L
    if np.any(ext > 0) and np.any(ext <= 0):
        raise ValueError('a batch must be all with extension (L0 > L) or all without')
    n_p, n_e = split_elements(n_elements, L, L0)
    # node positions
    xp = L[:, None] * np.linspace(0.0, 1.0, n_p + 1)[None, :]
    if n_e:
        xe = L[:, None] + ext[:, None] * np.linspace(0.0, 1.0, n_e + 1)[None, 1:]
        x = np.concatenate([xp, xe], axis=1)
    else:
        x = xp
    ne = n_p + n_e
    le = np.diff(x, axis=1)                                  # (N, ne)
    D = d12(hp, hb, Ep, Eb) / 12.0                          # N m per unit width
    m_area = 2 * rho_p * hp + rho_b * hb                     # kg/m^2 of the laminate
    mp = Ep * np.abs(d31) * (hb + hp)                        # N per V per unit width
    is_p = np.arange(ne) < n_p
    ke = np.zeros((nb, ne, 4, 4))
    me = np.zeros_like(ke)
    fe = np.zeros((nb, ne, 4))
    for g in range(_GX.size):
        xi = _GX[g]
        xg = x[:, :-1] + le * xi                             # (N, ne)
        width = np.where(is_p, A[:, None] + (B - A)[:, None] * np.minimum(xg / L[:, None], 1.0),
                         B[:, None])
        ei = np.where(is_p, width * D[:, None], width * (Eb * hb**3 / 12.0)[:, None])
        mu = np.where(is_p, width * m_area[:, None], width * (rho_b * hb)[:, None])
        mom = np.where(is_p, width * mp[:, None], 0.0)
        n, bb = _shape(xi, le)                               # (N, ne, 4)
        wl = _GW[g] * le
        ke += (wl * ei)[..., None, None] * bb[..., :, None] * bb[..., None, :]
        me += (wl * mu)[..., None, None] * n[..., :, None] * n[..., None, :]
        fe += (wl * mom)[..., None] * bb
    # Scatter-add: elements e and e + 2 share no dof, so even and odd elements are each
    # added with one advanced-index operation without duplicate indices.
    nd = 2 * ne + 2
    K = np.zeros((nb, nd, nd))
    M = np.zeros_like(K)
    f = np.zeros((nb, nd))
    loc = np.arange(4)
    for start in (0, 1):
        els = np.arange(start, ne, 2)
        dofs = 2 * els[:, None] + loc[None, :]               # (k, 4)
        ii = dofs[:, :, None]
        jj = dofs[:, None, :]
        K[:, ii, jj] += ke[:, els]
        M[:, ii, jj] += me[:, els]
        f[:, dofs] += fe[:, els]
    M[:, -2, -2] += tip_mass
    return dict(K=K[:, 2:, 2:], M=M[:, 2:, 2:], f=f[:, 2:], x=x, tip=2 * ne - 2)


def first_mode(K, M, iterations=100, tol=1e-9):
    """
    Return the lowest eigenpair of ``K phi = w^2 M phi`` by inverse iteration.

    :param K: stiffness, shape ``(N, n, n)``, N/m.
    :param M: mass, same shape, kg.
    :returns: ``(omega2, phi)``: squared circular frequency (rad^2/s^2, shape ``(N,)``)
        and the mode shape (shape ``(N, n)``, unit M-norm). Converges fast because the
        second bending mode of a cantilever is about 6x higher in frequency.
    """
    g = np.linalg.solve(K, M)                                # K^-1 M, shape (N, n, n)
    phi = np.ones(K.shape[:2] + (1,))
    lam_old = np.zeros(K.shape[0])
    for _ in range(iterations):
        phi = g @ phi
        phi = phi / np.sqrt(np.sum(phi * (M @ phi), axis=(1, 2)))[:, None, None]
        lam = np.sum(phi * (K @ phi), axis=(1, 2))
        if np.all(np.abs(lam - lam_old) <= tol * lam):
            break
        lam_old = lam
    phi = phi[..., 0]
    return lam, phi


def solve(voltage, A, B, L, L0, hp, hb, Ep, Eb, d31, rho_p, rho_b, tip_mass=0.0,  # noqa: N803
          n_elements=40, shapes=False):
    """
    Solve statics and the first mode of a batch of beams (see :func:`assemble`).

    :param voltage: drive voltage, V (scalar or shape ``(N,)``).
    :param shapes: also return node positions and free deflection at every node.
    :returns: dict of arrays of shape ``(N,)``: ``free_tip_m`` (free output displacement
        at x = L0 at ``voltage``, m), ``compliance_m_per_n`` and ``stiffness_n_per_m``
        (static, for a force at x = L0), ``blocked_force_n`` (= free_tip_m x stiffness,
        N), ``omega_n_rad_s``, ``first_mode_hz``, ``modal_mass_tip_kg`` (first mode
        normalised to 1 at x = L0: kinetic-energy equivalent mass at the output point),
        ``modal_stiffness_n_per_m`` (= omega_n^2 x modal_mass_tip_kg) and, with
        ``shapes``, ``x_m`` and ``deflection_m`` of shape ``(N, nodes)``.
    """
    sys = assemble(A, B, L, L0, hp, hb, Ep, Eb, d31, rho_p, rho_b, tip_mass, n_elements)
    K, M, f, tip = sys['K'], sys['M'], sys['f'], sys['tip']
    nb, n = f.shape
    rhs = np.zeros((nb, n, 2))
    rhs[:, :, 0] = f * np.broadcast_to(np.asarray(voltage, dtype=float), (nb,))[:, None]
    rhs[:, tip, 1] = 1.0
    u = np.linalg.solve(K, rhs)
    free = u[:, tip, 0]
    comp = u[:, tip, 1]
    lam, phi = first_mode(K, M)
    m_tip = 1.0 / phi[:, tip] ** 2          # phi has unit M-norm
    out = dict(free_tip_m=free, compliance_m_per_n=comp, stiffness_n_per_m=1.0 / comp,
               blocked_force_n=free / comp, omega_n_rad_s=np.sqrt(lam),
               first_mode_hz=np.sqrt(lam) / (2 * np.pi), modal_mass_tip_kg=m_tip,
               modal_stiffness_n_per_m=lam * m_tip)
    if shapes:
        w = np.concatenate([np.zeros((nb, 1)), u[:, 0::2, 0]], axis=1)
        out.update(x_m=sys['x'], deflection_m=w)
    return out


def solve_grouped(voltage, n_elements=40, **geom):
    """
    Call :func:`solve` on a batch that may mix beams with and without an extension.

    Beams with ``L0 > L`` and with ``L0 == L`` are solved as two batches and the results
    put back in the input order. ``geom`` holds the SI arrays named as in :func:`solve`.
    """
    arrays = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in geom.items()}
    arrays['voltage'] = np.atleast_1d(np.asarray(voltage, dtype=float))
    bc = np.broadcast_arrays(*arrays.values())
    arrays = dict(zip(arrays.keys(), bc))
    has_ext = arrays['L0'] > arrays['L']
    out = {}
    for mask in (has_ext, ~has_ext):
        if not np.any(mask):
            continue
        sub = {k: v[mask] for k, v in arrays.items()}
        res = solve(n_elements=n_elements, **sub)
        for k, v in res.items():
            if k not in out:
                out[k] = np.empty(mask.shape, dtype=float)
            out[k][mask] = v
    return out
