# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align identify``: identify a PI hysteresis model from a CSV or a rosbag2.

Writes the model as a ROS params file (``thresholds_v``, ``weights_m_per_v`` under
``hysteresis_compensator``), the format the compensator node loads. A model that is
not invertible is never written.
"""

from pathlib import Path
import sys

import numpy as np

from fiber_align.analysis.bag import read_hysteresis_experiment
from fiber_align.config import load_params
from fiber_align.hysteresis import data as hdata
from fiber_align.hysteresis.identify import identify, METHODS


def _positive_int(text):
    """Parse a positive integer (argparse type)."""
    import argparse
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError('%r is not an integer' % text) from None
    if v < 1:
        raise argparse.ArgumentTypeError('must be >= 1, got %d' % v)
    return v


def register(subparsers):
    """Add the ``identify`` sub-command."""
    p = subparsers.add_parser(
        'identify', help='identify a PI hysteresis model from (t, voltage, displacement)',
        description='Identify an invertible Prandtl-Ishlinskii model. DATA is a CSV with '
                    'columns t,voltage_v,displacement_m (s, V, m) or a rosbag2 directory '
                    'with the drive_voltage and displacement topics.')
    p.add_argument('data', metavar='DATA', help='CSV file or rosbag2 directory')
    p.add_argument('--method', choices=METHODS, default=None,
                   help='identification method (default from config/identify.yaml: lsq)')
    p.add_argument('--operators', type=_positive_int, default=None, metavar='N',
                   help='number of play operators (default 10)')
    p.add_argument('--seed', type=int, default=0, metavar='S', help='PSO seed (default 0)')
    p.add_argument('--config', default='identify.yaml',
                   help='params file with the identification settings')
    p.add_argument('--out', required=True, metavar='MODEL.yaml',
                   help='where to write the model (ROS params file)')
    p.add_argument('--json', action='store_true', help='print the fit report as JSON')
    p.add_argument('--plot', metavar='FILE', default=None,
                   help='draw measured vs model loop and the error against voltage')
    p.set_defaults(func=run, paths={'DATA': 'in-any', '--config': 'in-config',
                                    '--out': 'out-file', '--plot': 'out-file'})


def read_data(path):
    """Return ``(t, u, y)`` (s, V, m) from a CSV file or a rosbag2 directory."""
    p = Path(path)
    if p.is_dir():
        return read_hysteresis_experiment(str(p))
    return hdata.load_csv(p)


def plot_fit(path, u, y, result):
    """Draw the measured and model loops and the error against voltage (um for people)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    a1.plot(u, y * 1e6, '.', ms=2, label='measured')
    a1.plot(u, result.fitted_m * 1e6, '-', lw=1, label='model (%s)' % result.method)
    a1.set_xlabel('voltage (V)')
    a1.set_ylabel('displacement (um)')
    a1.legend()
    a1.grid(True, alpha=0.3)
    err = (result.fitted_m - y) * 1e6
    a2.plot(u, err, '.', ms=2, color='0.5', label='error')
    bins = result.error_vs_voltage
    c = np.array([b['voltage_v'] for b in bins])
    m = np.array([b['max_abs_error_m'] for b in bins]) * 1e6
    a2.fill_between(c, -m, m, alpha=0.25, label='max |error| per bin')
    a2.set_xlabel('voltage (V)')
    a2.set_ylabel('model - measured (um)')
    a2.set_title('RMS %.3g um, max %.3g um' % (
        result.rms_error_m * 1e6, result.max_error_m * 1e6))
    a2.legend()
    a2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(args):
    """Run ``identify``; return the exit code."""
    t, u, y = read_data(args.data)
    settings = load_params(args.config, 'identify')
    method = args.method or settings['method']
    if method not in METHODS:
        raise ValueError('method %r in %s is not one of %s'
                         % (method, args.config, ', '.join(METHODS)))
    res = identify(t, u, y, method=method, n_operators=args.operators, seed=args.seed,
                   config=args.config, settings=settings)
    out = Path(args.out)
    if out.parent and not out.parent.is_dir():
        raise ValueError('output directory %s does not exist' % out.parent)
    source = 'fiber-align identify --method %s (%s)' % (method, Path(args.data).name)
    res.model.save(out, extra={'model_source': source,
                               'fit_rms_error_m': res.rms_error_m,
                               'fit_max_error_m': res.max_error_m})
    if args.plot:
        plot_fit(args.plot, np.asarray(u, float), np.asarray(y, float), res)
    if args.json:
        print(res.to_json())
    else:
        print('%s: %d operators, RMS error %.4g um, max %.4g um, %.3f s -> %s'
              % (method, res.model.n, res.rms_error_m * 1e6, res.max_error_m * 1e6,
                 res.seconds, out), file=sys.stdout)
    return 0
