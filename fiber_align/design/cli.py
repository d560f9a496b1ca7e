# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align design``: print the design figures of an actuator config, write plots.

Usage: ``fiber-align design [--config FILE] [--voltage V] [--json] [--plots DIR]``.
Defaults: ``--config actuator.yaml`` (paper Table 2) and ``--voltage`` = the config's
``v_max``. Errors (bad file, key, value or voltage) exit 2 with one line naming the flag or
field and the allowed range.
"""

import json
from pathlib import Path

from fiber_align.config import ConfigError
from fiber_align.design import load_actuator, report
from fiber_align.design.plots import write_all

UM = 1e6


def register(subparsers):
    """Add the ``design`` sub-command to ``subparsers``."""
    p = subparsers.add_parser(
        'design', help='static, blocked-force and modal figures of the bimorph',
        description='Design model of the trapezoidal piezo bimorph (paper equations 3-5, '
                    'beam FE for blocked force and first mode).')
    p.add_argument('--config', metavar='FILE', default='actuator.yaml',
                   help='actuator params file, or a name in config/ (default: %(default)s, '
                        'paper Table 2; actuator_table1.yaml is Table 1)')
    p.add_argument('--voltage', metavar='V', type=float, default=None,
                   help='drive voltage in V (default: v_max of the config); allowed '
                        '0..max_field_v_per_m x piezo_thickness_m')
    p.add_argument('--json', action='store_true', help='print one JSON object (SI units)')
    p.add_argument('--plots', metavar='DIR', default=None,
                   help='write deflection, blocked-force and Figure 7-10 sweep PNGs to DIR')
    # checked by fiber-align before run (fiber_align.tools.paths)
    p.set_defaults(func=run, paths={'--config': 'in-config', '--plots': 'out-dir'})
    return p


def run(args):
    """Run ``design`` with parsed ``args``; return the exit code."""
    try:
        act = load_actuator(args.config)
    except ConfigError as exc:
        raise ConfigError('--config %s: %s' % (args.config, exc)) from None
    voltage = act.v_max if args.voltage is None else args.voltage
    try:
        act.check_voltage(voltage, name='--voltage')
    except ValueError as exc:
        raise ValueError(str(exc)) from None
    rep = report(act, voltage)
    if args.plots:
        try:
            paths = write_all(act, voltage, args.plots)
        except OSError as exc:
            raise ValueError('--plots %s: cannot write plots there (%s)'
                             % (args.plots, exc.strerror or exc)) from None
        rep['plots'] = [str(p) for p in paths]
    if args.json:
        print(json.dumps(rep, sort_keys=True))
    else:
        print(format_table(rep, args.config))
    return 0


def format_table(rep, source=''):
    """Return a readable multi-line table of a :func:`~fiber_align.design.report` dict."""
    g = rep['geometry']
    rows = [
        ('config', '%s (%s)' % (Path(str(source)).name, g.get('geometry_source') or '-')),
        ('A / B (base / tip width)', '%.0f / %.0f um' % (
            g['base_width_m'] * UM, g['tip_width_m'] * UM)),
        ('L / L0 (piezo / total length)', '%.0f / %.0f um' % (
            g['piezo_length_m'] * UM, g['total_length_m'] * UM)),
        ('hp / hb (piezo / metal thickness)', '%.0f / %.0f um' % (
            g['piezo_thickness_m'] * UM, g['metal_thickness_m'] * UM)),
        ('voltage', '%.1f V (field %.3f V/um, limit %.1f V, v_max %.1f V)' % (
            rep['voltage_v'], rep['field_v_per_m'] / UM, rep['field_limit_v'],
            rep['v_max_v'])),
        ('tip displacement (eq. 5)', '%.2f um' % (rep['tip_displacement_m'] * UM)),
        ('tip displacement (beam FE)', '%.2f um' % (rep['tip_displacement_fe_m'] * UM)),
        ('blocked force trapezoid', '%.3f N' % rep['blocked_force_n']),
        ('blocked force rectangle', '%.3f N' % rep['blocked_force_rectangle_n']),
        ('blocked force ratio', '%.3f' % rep['blocked_force_ratio']),
        ('tip stiffness', '%.1f N/m' % rep['stiffness_n_per_m']),
        ('first bending mode', '%.1f Hz (omega_n %.0f rad/s)' % (
            rep['first_mode_hz'], rep['omega_n_rad_s'])),
        ('alpha (displacement per volt)', '%.4f um/V' % (rep['alpha_m_per_v'] * UM)),
        ('modal mass (k / omega_n^2)', '%.2f mg' % (rep['modal_mass_kg'] * 1e6)),
        ('total mass', '%.2f mg' % (rep['mass_kg'] * 1e6)),
    ]
    if rep['voltage_v'] > rep['v_max_v']:
        rows.append(('note', 'voltage above the drive limit v_max'))
    for p in rep.get('plots', []):
        rows.append(('plot', p))
    w = max(len(k) for k, _ in rows)
    return '\n'.join('%-*s  %s' % (w, k, v) for k, v in rows)
