# SPDX-License-Identifier: Apache-2.0
"""
Design figures of one actuator: free displacement, blocked force, first mode, report.

Blocked force (paper Section 2, Figure 3): the force at the output point x = L0 that
holds the driven bimorph at zero displacement, i.e. free tip displacement x static tip
stiffness. The piezo moment per unit width is uniform, so the free deflection does not
depend on the width; the tip stiffness does, which is why the trapezoid (A > B) pushes
harder than the rectangle (width B everywhere) at the same displacement.

Single-degree-of-freedom equivalent used by the simulated actuator (SEED-NOTES
section 5): ``alpha`` = free displacement per volt at x = L0 (m/V); ``omega_n`` = first
bending mode of the beam FE (rad/s); ``k`` = static tip stiffness at x = L0 (N/m);
``m = k / omega_n^2`` (kg), so that ``sqrt(k / m) = omega_n`` exactly and the static gain
and the resonance both match the beam.
"""

import numpy as np

from fiber_align.design import fe
from fiber_align.design.model import tip_displacement, tip_slope


def _solve(actuator, voltage, shapes=False):
    """Run the beam FE of ``actuator`` at ``voltage`` (V); return scalar results (SI)."""
    g = actuator.geometry()
    res = fe.solve(voltage, n_elements=actuator.fe_elements, shapes=shapes, **g)
    return {k: (v[0] if v.ndim == 1 else v[0]) for k, v in res.items()}


def dynamics(actuator):
    """
    Return the lumped plant parameters of ``actuator`` (SI).

    :returns: dict with ``alpha_m_per_v`` (free displacement per volt at x = L0, m/V),
        ``omega_n_rad_s`` and ``first_mode_hz`` (first bending resonance of the laminate
        with its extension and tip mass), ``stiffness_n_per_m`` (static tip stiffness at
        x = L0) and ``modal_mass_kg`` (= stiffness / omega_n^2).
    """
    r = _solve(actuator, 1.0)
    k = float(r['stiffness_n_per_m'])
    w = float(r['omega_n_rad_s'])
    return dict(alpha_m_per_v=float(r['free_tip_m']), omega_n_rad_s=w,
                first_mode_hz=float(r['first_mode_hz']), stiffness_n_per_m=k,
                modal_mass_kg=k / w**2)


def blocked_force(actuator, voltage):
    """
    Return the blocked force at x = L0 for ``voltage`` (V), N: trapezoid and rectangle.

    :returns: ``(trapezoid_n, rectangle_n)``; the rectangle has width B everywhere.
    """
    actuator.check_voltage(voltage)
    t = _solve(actuator, voltage)
    r = _solve(actuator.rectangle(), voltage)
    return float(t['blocked_force_n']), float(r['blocked_force_n'])


def report(actuator, voltage):
    """
    Return every design figure of ``actuator`` at ``voltage`` (V) as a JSON-ready dict.

    All values SI (m, N, Hz, rad/s, kg, V, V/m). ``tip_displacement_m`` is equation 5;
    ``tip_displacement_fe_m`` the beam FE (they agree to round-off). Raises ValueError if
    ``voltage`` is outside ``0..max_field_v_per_m x hp``.
    """
    v = actuator.check_voltage(voltage)
    g = actuator.geometry()
    t = _solve(actuator, v)
    r = _solve(actuator.rectangle(), v)
    dyn = dynamics(actuator)
    out = dict(
        voltage_v=v,
        field_v_per_m=float(actuator.field_v_per_m(v)),
        field_limit_v=float(actuator.field_limit_v),
        max_field_v_per_m=float(actuator.max_field_v_per_m),
        v_max_v=float(actuator.v_max),
        tip_displacement_m=float(tip_displacement(v, **g)),
        tip_displacement_fe_m=float(t['free_tip_m']),
        tip_slope_rad=float(tip_slope(v, **g)),
        blocked_force_n=float(t['blocked_force_n']),
        blocked_force_rectangle_n=float(r['blocked_force_n']),
        blocked_force_ratio=float(t['blocked_force_n'] / r['blocked_force_n']),
        stiffness_rectangle_n_per_m=float(r['stiffness_n_per_m']),
        first_mode_rectangle_hz=float(r['first_mode_hz']),
        modal_mass_tip_kg=float(t['modal_mass_tip_kg']),
        mass_kg=float(total_mass(actuator)),
    )
    out.update(dyn)
    out['geometry'] = {k: val for k, val in actuator.as_dict().items()}
    return out


def total_mass(actuator):
    """Return the mass of the laminate, extension and tip mass, kg."""
    a = actuator
    area_p = 0.5 * (a.A + a.B) * a.L
    return (area_p * (2 * a.piezo_density_kg_per_m3 * a.hp + a.metal_density_kg_per_m3 * a.hb)
            + a.B * (a.L0 - a.L) * a.metal_density_kg_per_m3 * a.hb + a.tip_mass_kg)


def deflection_fe(actuator, voltage):
    """Return ``(x, v)``: FE node positions (m) and free deflection (m) at ``voltage`` (V)."""
    r = _solve(actuator, voltage, shapes=True)
    return np.asarray(r['x_m']), np.asarray(r['deflection_m'])
