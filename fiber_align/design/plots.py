# SPDX-License-Identifier: Apache-2.0
"""
PNG plots of the design model: deflection, blocked force, Figures 7-10 sweeps.

Inputs are SI; axes are labelled in micrometres (lengths, displacements), N and Hz.
Uses the non-interactive Agg backend, so it runs headless.
"""

from pathlib import Path

import numpy as np

from fiber_align.design import fe
from fiber_align.design.analysis import deflection_fe
from fiber_align.design.model import deflection
from fiber_align.design.sweeps import FIGURES, sweep

UM = 1e6


def _pyplot():
    """Return matplotlib.pyplot on the Agg backend."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _save(plt, fig, path):
    """Lay out ``fig``, write it to ``path`` (PNG/PDF/SVG by suffix), close it; return the path."""
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def plot_deflection(actuator, voltage, path):
    """Write the free deflection curve v(x) over [0, L0] at ``voltage`` (V) to ``path``."""
    plt = _pyplot()
    x = np.linspace(0.0, actuator.L0, 400)
    v = deflection(x, voltage, **actuator.geometry())
    xf, vf = deflection_fe(actuator, voltage)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    ax.plot(x * UM, v * UM, label='equation 3 + rigid extension')
    ax.plot(xf * UM, vf * UM, 'o', ms=3, label='beam FE nodes')
    ax.axvline(actuator.L * UM, color='0.6', ls='--', lw=0.8, label='end of piezo layers (L)')
    ax.set_xlabel('position along the actuator x (um)')
    ax.set_ylabel('deflection v (um)')
    ax.set_title('Free deflection at %.0f V (output %.1f um at L0)' % (voltage, v[-1] * UM))
    ax.grid(True, alpha=0.3)
    ax.legend()
    return _save(plt, fig, path)


def plot_blocked_force(actuator, voltage, path):
    """Write output displacement vs tip force (paper Figure 3) for both shapes to ``path``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for label, act in (('trapezoid A = %.0f um' % (actuator.A * UM), actuator),
                       ('rectangle B = %.0f um' % (actuator.B * UM), actuator.rectangle())):
        r = fe.solve(voltage, n_elements=act.fe_elements, **act.geometry())
        free, comp = r['free_tip_m'][0], r['compliance_m_per_n'][0]
        fb = free / comp
        f = np.linspace(0.0, fb, 50)
        ax.plot(f, (free - f * comp) * UM, label='%s: blocked %.3f N' % (label, fb))
    ax.set_xlabel('force at the output point x = L0 (N)')
    ax.set_ylabel('output displacement (um)')
    ax.set_title('Blocked force at %.0f V (beam FE)' % voltage)
    ax.grid(True, alpha=0.3)
    ax.legend()
    return _save(plt, fig, path)


def plot_sweep(actuator, name, path, n=41):
    """Write a Figure 7-10 sweep (see :data:`~fiber_align.design.sweeps.FIGURES`)."""
    plt = _pyplot()
    s = sweep(actuator, name, n=n)
    _, _, _, xlabel, fig_no = FIGURES[name]
    xv = s['values'] * (1.0 if name == 'rh' else UM)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(6.4, 6.4), sharex=True)
    ax1.plot(xv, s['tip_displacement_m'] * UM, label='equation 5')
    ax1.plot(xv, s['tip_displacement_fe_m'] * UM, 'o', ms=3, label='beam FE')
    bad = ~s['within_field_limit']
    if np.any(bad):
        ax1.plot(xv[bad], s['tip_displacement_m'][bad] * UM, 'x', color='red',
                 label='field above %.2g V/um' % (actuator.max_field_v_per_m / UM))
    ax1.set_ylabel('output displacement (um)')
    ax1.set_title('Figure %d sweep at %.0f V' % (fig_no, s['voltage_v']))
    ax1.grid(True, alpha=0.3)
    ax1.legend()
    ax2.plot(xv, s['blocked_force_n'], label='trapezoid')
    ax2.plot(xv, s['blocked_force_rectangle_n'], label='rectangle (width B)')
    ax2.set_xlabel(xlabel)
    ax2.set_ylabel('blocked force (N)')
    ax2.grid(True, alpha=0.3)
    ax2.legend()
    return _save(plt, fig, path)


def write_all(actuator, voltage, directory, sweep_base=None):
    """
    Write every design plot into ``directory``; return the list of paths.

    :param sweep_base: the design the Figure 7-10 sweeps start from (default
        ``actuator``; the paper's figures start from Table 1).
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = [plot_deflection(actuator, voltage, d / 'deflection.png'),
           plot_blocked_force(actuator, voltage, d / 'blocked_force.png')]
    base = sweep_base or actuator
    for name, spec in FIGURES.items():
        out.append(plot_sweep(base, name, d / ('figure%d_sweep_%s.png' % (spec[4], name))))
    return out
