# SPDX-License-Identifier: Apache-2.0
"""
Vectorised parameter sweeps (paper Figures 7-10) and many-geometry evaluation.

:func:`evaluate` takes arrays of geometries (SI) and returns, for each, the closed-form
output displacement (equation 5), the beam-FE output displacement, the blocked force of
the trapezoid and of its rectangular counterpart, the static tip stiffness and the first
bending mode, all as arrays from one batched FE run (no Python loop over geometries).

Figure definitions follow the paper (Section 4): every sweep starts from the Table 1
design at 100 V and varies one parameter:

- Figure 7: A from 6 mm to 10 mm.
- Figure 8: L from 6 mm to 18 mm with L0 = L + 0.5 mm (the extension kept at 500 um).
- Figure 9: hp from 50 um to 150 um.
- Figure 10: rh = hb / hp from 0.5 to 1.5 with hp = 125 um.
"""

import numpy as np

from fiber_align.design import fe
from fiber_align.design.model import tip_displacement

FIGURES = {
    # name: (parameter, start, stop, axis label, paper figure)
    'A': ('base_width_m', 6.0e-3, 10.0e-3, 'base width A (um)', 7),
    'L': ('piezo_length_m', 6.0e-3, 18.0e-3, 'piezo length L (um), L0 = L + 500 um', 8),
    'hp': ('piezo_thickness_m', 50.0e-6, 150.0e-6, 'piezo thickness hp (um)', 9),
    'rh': ('rh', 0.5, 1.5, 'thickness ratio rh = hb / hp (-)', 10),
}
SWEEP_VOLTAGE_V = 100.0


def evaluate(voltage, n_elements=None, **geom):
    """
    Evaluate many geometries at once; every value may be an array (SI).

    :param voltage: drive voltage, V (scalar or array).
    :param n_elements: FE elements per beam (default: the FE default, 40).
    :param geom: ``A, B, L, L0, hp, hb, Ep, Eb, d31, rho_p, rho_b, tip_mass`` as in
        :meth:`fiber_align.design.model.Actuator.geometry`.
    :returns: dict of arrays: ``tip_displacement_m`` (equation 5), ``tip_displacement_fe_m``,
        ``blocked_force_n``, ``blocked_force_rectangle_n``, ``stiffness_n_per_m``,
        ``first_mode_hz``, ``field_v_per_m``.
    """
    kw = {} if n_elements is None else dict(n_elements=int(n_elements))
    trap = fe.solve_grouped(voltage, **kw, **geom)
    rect_geom = dict(geom, A=geom['B'])
    rect = fe.solve_grouped(voltage, **kw, **rect_geom)
    disp = tip_displacement(voltage, **geom)
    shape = trap['free_tip_m'].shape
    return dict(tip_displacement_m=np.broadcast_to(disp, shape).astype(float),
                tip_displacement_fe_m=trap['free_tip_m'],
                blocked_force_n=trap['blocked_force_n'],
                blocked_force_rectangle_n=rect['blocked_force_n'],
                stiffness_n_per_m=trap['stiffness_n_per_m'],
                first_mode_hz=trap['first_mode_hz'],
                field_v_per_m=np.broadcast_to(np.abs(voltage) / np.asarray(geom['hp']),
                                              shape).astype(float))


def sweep(actuator, name, n=41, voltage=SWEEP_VOLTAGE_V, values=None, n_elements=None):
    """
    Sweep one parameter of ``actuator`` as in the paper's Figures 7-10.

    :param actuator: the base design (the paper uses Table 1).
    :param name: ``'A'``, ``'L'``, ``'hp'`` or ``'rh'`` (see :data:`FIGURES`).
    :param n: number of points between the figure's limits (ignored with ``values``).
    :param voltage: drive voltage, V (the field limit is not enforced here: the result
        carries ``field_v_per_m`` and ``within_field_limit`` so plots can mark it).
    :param values: explicit parameter values (SI; rh dimensionless).
    :param n_elements: FE elements per beam (default ``actuator.sweep_fe_elements``).
    :returns: dict with ``name``, ``values`` and the arrays of :func:`evaluate`.
    """
    if name not in FIGURES:
        raise ValueError('sweep %r unknown; allowed: %s' % (name, ', '.join(FIGURES)))
    _, lo, hi, _, _ = FIGURES[name]
    vals = np.linspace(lo, hi, int(n)) if values is None else np.asarray(values, dtype=float)
    g = {k: np.full(vals.shape, v, dtype=float) for k, v in actuator.geometry().items()}
    ext = actuator.L0 - actuator.L
    if name == 'A':
        g['A'] = vals
    elif name == 'L':
        g['L'] = vals
        g['L0'] = vals + ext
    elif name == 'hp':
        g['hp'] = vals
    else:
        g['hb'] = vals * g['hp']
    out = evaluate(voltage, n_elements=n_elements or actuator.sweep_fe_elements, **g)
    out['within_field_limit'] = out['field_v_per_m'] <= actuator.max_field_v_per_m
    out.update(name=name, values=vals, voltage_v=float(voltage))
    return out
