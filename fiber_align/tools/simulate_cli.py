# SPDX-License-Identifier: Apache-2.0
"""``fiber-align simulate`` and ``fiber-align fuzzy-surface``."""

import json
import math

from fiber_align.analysis import alignment_plots
from fiber_align.config import load_params
from fiber_align.control.factory import CONTROLLERS
from fiber_align.jsonout import json_clean
from fiber_align.control.fuzzy import FuzzyInference
from fiber_align.plant.actuator import KINDS as PLANTS
from fiber_align.simulation import (alignment2d_scenarios, alignment_scenarios,
                                    array_scenarios, scenarios, simulate, station_scenarios)
from fiber_align.tools import runs_cli
from fiber_align.tools.common import UsageError


def register(sub):
    """Add the ``simulate`` and ``fuzzy-surface`` sub-commands."""
    p = sub.add_parser('simulate', help='closed-loop simulation of a control scenario')
    p.add_argument('--scenario', default='step',
                   help='%s; %s run the alignment sequencer; %s the two-axis sequencer and '
                        'its hill-climb baseline; %s the coupled input/output station and '
                        'its serial baseline; %s the fiber array in x, y and roll and its '
                        'serial baseline (fiber_align.simulation.harness)'
                        % tuple(' | '.join(n) for n in (scenarios.NAMES,) + tuple(
                            scenarios.MACHINE_SCENARIOS.values())))
    p.add_argument('--controller', default='composite',
                   help='open-loop | feedforward | pid | fuzzy | composite | composite-pid')
    p.add_argument('--rate', type=float, default=None, help='control rate, Hz')
    p.add_argument('--duration', type=float, default=None, help='run length, s')
    p.add_argument('--seed', type=int, default=0, help='sensor-noise seed')
    p.add_argument('--noise', choices=('on', 'off'), default='off')
    p.add_argument('--plant', default='default', help='default | paper | linear')
    p.add_argument('--model', default=None,
                   help='feedforward PI model file, or "identify" (default: the model in '
                        'config/compensator.yaml, identified on the default plant; for '
                        'another --plant, identified on that plant)')
    p.add_argument('--json', action='store_true', help='print the metrics as JSON')
    p.add_argument('--plot', default=None, help='write a plot (PNG/PDF/SVG)')
    p.add_argument('--csv', default=None, help='write the arrays as CSV')
    p.add_argument('--compare', action='store_true',
                   help='every controller on every scenario: the paper-style table')
    al = p.add_argument_group('alignment scenarios (align, switch, track)')
    al.add_argument('--loop', choices=('composite', 'ideal'), default=None,
                    help='closed loop under the sequencer: the control core\'s composite '
                         'loop (default) or a first-order stand-in')
    al.add_argument('--cycles', type=int, default=None,
                    help='switch: off/on cycles (default 5)')
    al.add_argument('--slot', type=float, default=None, metavar='M',
                    help='slot (output core) position, m (default: random in the range)')
    al.add_argument('--drift', type=float, default=None, metavar='M_PER_S',
                    help='track: slot drift, m/s (default 1e-6)')
    runs_cli.add_simulate_options(p)
    p.set_defaults(func=cmd_simulate, paths={'--model': 'in-config', '--plot': 'out-file',
                                             '--csv': 'out-file'})
    q = sub.add_parser('fuzzy-surface', help='the three fuzzy rule surfaces')
    q.add_argument('--points', type=int, default=41, help='grid points per axis')
    q.add_argument('--json', action='store_true', help='print JSON rows')
    q.add_argument('--plot', default=None, help='write a plot (PNG/PDF/SVG)')
    q.set_defaults(func=cmd_fuzzy_surface, paths={'--plot': 'out-file'})


ALIGN_SCENARIOS = scenarios.MACHINE_SCENARIOS['one']
STATION_SCENARIOS = (scenarios.MACHINE_SCENARIOS['station']
                     + scenarios.MACHINE_SCENARIOS['array'])
#: The machine of every alignment scenario (its module's ``run_cli``).
MACHINES = {name: module for module in (alignment_scenarios, alignment2d_scenarios,
                                        station_scenarios, array_scenarios)
            for name in module.SCENARIOS}
#: The figure of a machine's run (``--plot``), where it has one.
PLOTS = {alignment_scenarios: alignment_plots.plot_run,
         alignment2d_scenarios: alignment_plots.plot_run2d}


def _check_alignment_args(args):
    """Raise UsageError for out-of-range alignment options (SI units)."""
    if args.cycles is not None and args.cycles < 1:
        raise UsageError('--cycles must be >= 1, got %d' % args.cycles)
    for name, v in (('--slot', args.slot), ('--drift', args.drift),
                    ('--duration', args.duration), ('--rate', args.rate)):
        if v is not None and not math.isfinite(v):
            raise UsageError('%s must be a finite number, got %r' % (name, v))
    if args.slot is not None and not 0.0 <= args.slot <= 1e-3:
        raise UsageError('--slot is in metres (e.g. 40e-6), got %g' % args.slot)
    if args.drift is not None and abs(args.drift) > 1e-3:
        raise UsageError('--drift is in m/s (e.g. 1e-6), got %g' % args.drift)
    if args.duration is not None and not args.duration > 0:
        raise UsageError('--duration must be > 0 s, got %g' % args.duration)
    if args.rate is not None and not args.rate > 0:
        raise UsageError('--rate must be > 0 Hz, got %g' % args.rate)


def _fmt(v, scale=1.0, digits=3):
    """Format a metric for the table (None -> '-')."""
    if v is None:
        return '-'
    if isinstance(v, float) and math.isinf(v):
        return 'inf'
    return '%.*f' % (digits, v * scale)


def cmd_simulate(args):
    """Run ``simulate``; return an exit code."""
    if args.scenario in STATION_SCENARIOS:      # the coupled input/output station
        _check_alignment_args(args)
        extra = [o for o, v in (('--cycles', args.cycles), ('--slot', args.slot),
                                ('--drift', args.drift), ('--duration', args.duration))
                 if v is not None]
        if extra:
            raise UsageError('%s do not apply to --scenario %s'
                             % (', '.join(extra), args.scenario))
    record = runs_cli.recorder(args)     # None without --catalog (or with none)
    if args.scenario in MACHINES:
        _check_alignment_args(args)
        module = MACHINES[args.scenario]
        plot = {'plot': PLOTS[module]} if module in PLOTS else {}
        if record is None:
            return module.run_cli(args, **plot)
        args.on_result, finish = record
        try:
            return module.run_cli(args, **plot)
        finally:
            finish()
    extra = [o for o, v in (('--loop', args.loop), ('--cycles', args.cycles),
                            ('--slot', args.slot), ('--drift', args.drift)) if v is not None]
    if extra:
        raise UsageError('%s only apply to --scenario %s'
                         % (', '.join(extra), '|'.join(ALIGN_SCENARIOS)))
    if args.rate is not None and not args.rate > 0:
        raise UsageError('--rate must be > 0 Hz, got %g' % args.rate)
    if args.duration is not None and not args.duration > 0:
        raise UsageError('--duration must be > 0 s, got %g' % args.duration)
    if args.plant not in PLANTS:
        raise UsageError('unknown --plant %r (allowed: %s)'
                         % (args.plant, ', '.join(PLANTS)))
    if args.model is not None and args.model not in ('identify', 'identified'):
        simulate.check_model_file(args.model)
    noise = args.noise == 'on'
    if args.compare:
        rows = []
        for sc in ('step', 'sine', 'triangle'):
            for c in CONTROLLERS:
                res = simulate.run(sc, c, rate_hz=args.rate, duration_s=args.duration,
                                   seed=args.seed, noise=noise, plant=args.plant,
                                   model=args.model)
                rows.append(res.metrics)
        if args.json:
            print(json.dumps(json_clean(rows), indent=1))
            return 0
        print('plant %s, rate %g Hz, noise %s (measured displacement, as analyze scores a '
              'bag; true_* keys in --json)' % (args.plant, rows[0]['rate_hz'], args.noise))
        print('| scenario | controller | settling ms | overshoot % | rise ms | '
              'RMS error um | max error um | max V |')
        print('|---|---|---|---|---|---|---|---|')
        for m in rows:
            print('| %s | %s | %s | %s | %s | %s | %s | %s |' % (
                m['scenario'], m['controller'], _fmt(m['settling_time_s'], 1e3, 2),
                _fmt(m['overshoot_pct'], 1, 2), _fmt(m['rise_time_s'], 1e3, 2),
                _fmt(m['rms_error_m'], 1e6, 4), _fmt(m['max_error_m'], 1e6, 4),
                _fmt(m['max_voltage_v'], 1, 1)))
        return 0
    if args.scenario not in scenarios.NAMES:
        raise UsageError('unknown --scenario %r (allowed: %s)'
                         % (args.scenario, ', '.join(scenarios.NAMES + scenarios.ALIGNMENT)))
    if args.controller not in CONTROLLERS:
        raise UsageError('unknown --controller %r (allowed: %s)'
                         % (args.controller, ', '.join(CONTROLLERS)))
    res = simulate.run(args.scenario, args.controller, rate_hz=args.rate,
                       duration_s=args.duration, seed=args.seed, noise=noise,
                       plant=args.plant, model=args.model)
    if args.csv:
        res.to_csv(args.csv)
    if args.plot:
        plot_result(res, args.plot)
    m = res.metrics
    if args.json:
        print(json.dumps(json_clean(m), indent=1))
    else:
        for k, v in m.items():
            if k == 'steps':
                for i, st in enumerate(v):
                    print('step %d: %.4g -> %.4g um at %.4g ms: settling %s ms, overshoot '
                          '%s %%' % (i + 1, st['from_m'] * 1e6, st['to_m'] * 1e6,
                                     st['t_step_s'] * 1e3,
                                     _fmt(st['settling_time_s'], 1e3, 2),
                                     _fmt(st['overshoot_pct'], 1, 2)))
            else:
                print('%s: %s' % (k, v))
    return 0


def plot_result(res, path):
    """Write reference, displacement, error and voltage of a run to ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    t_ms = res.t * 1e3
    if res.scenario != 'hysteresis-experiment':
        ax[0].plot(t_ms, res.r * 1e6, 'k--', label='reference')
        ax[1].plot(t_ms, (res.y_true - res.r) * 1e6)
    ax[0].plot(t_ms, res.y_true * 1e6, label='true displacement')
    ax[0].set_ylabel('displacement (um)')
    ax[0].legend()
    ax[0].set_title('%s, %s, %g Hz' % (res.scenario, res.controller, res.rate_hz))
    ax[1].set_ylabel('error (um)')
    ax[2].plot(t_ms, res.v, label='drive')
    ax[2].plot(t_ms, res.ff, label='feedforward')
    ax[2].plot(t_ms, res.fb, label='feedback')
    ax[2].set_ylabel('voltage (V)')
    ax[2].set_xlabel('time (ms)')
    ax[2].legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def cmd_fuzzy_surface(args):
    """Run ``fuzzy-surface``; return an exit code."""
    if args.points < 2 or args.points > 1001:
        raise UsageError('--points must be in 2..1001, got %d' % args.points)
    fis = FuzzyInference.from_params(
        load_params('controller.yaml', 'fuzzy_pid_controller')['fuzzy'])
    e, ec, out = fis.surface(args.points)
    if args.plot:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        fig = plt.figure(figsize=(15, 4.5))
        for i, name in enumerate(('dkp', 'dki', 'dkd')):
            axi = fig.add_subplot(1, 3, i + 1, projection='3d')
            axi.plot_surface(e, ec, out[i], cmap='viridis')
            axi.set_xlabel('E (um)')
            axi.set_ylabel('EC (um/ms)')
            axi.set_title('%s (before the scale factor)' % name)
        fig.tight_layout()
        fig.savefig(args.plot)
        plt.close(fig)
    if args.json:
        rows = [{'e': float(e[a, b]), 'ec': float(ec[a, b]), 'dkp': float(out[0, a, b]),
                 'dki': float(out[1, a, b]), 'dkd': float(out[2, a, b])}
                for a in range(args.points) for b in range(args.points)]
        print(json.dumps(rows))
    elif not args.plot:
        print('e ec dkp dki dkd')
        for a in range(args.points):
            for b in range(args.points):
                print('%.4g %.4g %.4f %.4f %.4f' % (e[a, b], ec[a, b], out[0, a, b],
                                                    out[1, a, b], out[2, a, b]))
    return 0
