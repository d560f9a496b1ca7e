# SPDX-License-Identifier: Apache-2.0
"""
``bringup``'s command line: options, their checks, and the graph they describe.

Options map onto the launch arguments (:func:`arguments`; the graph then as under ``ros2
launch``, :func:`fiber_align.graph.arguments.describe_run`) and parameter overrides.
"""

import argparse
import math
import os
import sys

from fiber_align.graph.arguments import ARGUMENTS, describe_run
from fiber_align.graph.description import check_namespace
from fiber_align.graph.params import GraphError, parse_overrides, PLANT, RECORDER

#: bringup's options that are no launch argument, of the simulated 1-D graph only:
#: (attribute, option); the launch arguments' are :func:`describe`'s.
ONE_AXIS_OPTIONS = (('rate', '--rate'), ('no_noise', '--no-noise'))


def _positive(kind, what):
    def conv(text):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError('%s: %r is not a number' % (what, text))
        if not (math.isfinite(v) and v > 0):
            raise argparse.ArgumentTypeError('%s must be > 0, got %r' % (what, text))
        return v
    return conv


def _namespace(text):
    try:                # the description's rule, as under ros2 launch
        return check_namespace(text)
    except GraphError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``bringup: error: ...``), exit 2."""

    def error(self, message):
        """Print one line naming what is wrong and what is allowed; exit 2."""
        self.exit(2, '%s: error: %s\n' % (self.prog, message))


#: bringup's option for each launch argument of :data:`ARGUMENTS` but ``composed``:
#: ``name -> (option, argparse keywords)``; its help is the launch argument's text.
OPTIONS = {
    'namespace': ('--namespace', dict(type=_namespace, default='')),
    'sync_mode': ('--sync', {}), 'controller': ('--controller', {}),
    'params_file': ('--params-file', dict(action='append', default=[])),
    'model_file': ('--model', dict(metavar='FILE')), 'record': ('--record', dict(metavar='DIR')),
    'scenario': ('--scenario', {}), 'rig': ('--rig', dict(action='store_true')),
    'station': ('--station', dict(action='store_true')), 'seed': ('--seed', dict(type=int)),
    'array': ('--array', dict(action='store_true')),
    'hardware': ('--hardware', dict(action='store_true')), 'port': ('--port', {}),
    'visa_resource': ('--visa-resource', {}), 'live': ('--live', dict(action='store_true')),
    'live_port': ('--live-port', dict(type=int, metavar='PORT')),
    'live_host': ('--live-host', dict(metavar='HOST')),
    'catalog': ('--catalog', dict(metavar='URL')),
    'snapshots': ('--snapshots', dict(metavar='DIR')),
}
#: What ``bringup`` does beyond starting the graph, by option.
NOTES = {
    'scenario': '; bringup runs it to its end (align: then --cycles switch cycles)',
    'rig': '; align2d, in lockstep compared with fiber-align simulate --scenario align2d',
    'station': '; align, in lockstep compared with fiber-align simulate --scenario station',
    'array': '; align, in lockstep compared with fiber-align simulate --scenario array',
    'hardware': '; align, --cycles, --hold; with --rig or --array the axes on one MDT693B',
}


def _dest(option):
    return option.lstrip('-').replace('-', '_')


def parse_args(argv):
    """Parse the command line (ROS arguments after ``--ros-args`` are ignored)."""
    if argv is None:
        argv = sys.argv[1:]
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    ap = _Parser(prog='bringup', description='Start the fiber_align graph, run a scenario, '
                 'record, stop, summarise.')
    for name, _, text, choices in ARGUMENTS:
        if name in OPTIONS:
            option, kw = OPTIONS[name]
            if choices and 'action' not in kw:
                kw = dict(kw, choices=[c for c in choices if c])
            text = text[len('true: '):] if text.startswith('true: ') else text
            ap.add_argument(option, help=text + NOTES.get(name, ''), **kw)
    layout = ap.add_mutually_exclusive_group()
    layout.add_argument('--composed', dest='composed', action='store_true', default=None,
                        help='the control nodes in one process (control_graph; default)')
    layout.add_argument('--multi-process', dest='composed', action='store_false',
                        help='one process per node')
    ap.add_argument('--duration', type=_positive(float, '--duration'), default=None,
                    help="scenario length (s of sample time; default: the scenario's); "
                    '--rig, --station: hold TRACKING this long after the cycles')
    ap.add_argument('--rate', type=_positive(float, '--rate'), default=None,
                    help='control rate (Hz)')
    ap.add_argument('--no-noise', action='store_true', help='sensor noise off')
    ap.add_argument('--cycles', type=int, default=None,
                    help='align: switch off/on cycles after TRACKING (default 5); --rig: '
                    'release / align cycles after the first TRACKING (default 0)')
    ap.add_argument('--part', metavar='P', default=None,
                    help='--rig, --station: set the sequencer\'s part_id to P-1, P-2, ... before '
                    'each align (the run catalogue\'s part of each alignment)')
    ap.add_argument('--storage', choices=('mcap', 'sqlite3'), default=None)
    ap.add_argument('-p', '--param', action='append', default=[], metavar='NODE:NAME:=VALUE',
                    help='override one parameter (NODE may be **)')
    ap.add_argument('--trace', metavar='CSV', help='write t_s,r_m,y_m of every sample')
    ap.add_argument('--summary', metavar='JSON', help='write the summary as JSON')
    ap.add_argument('--strict', action='store_true',
                    help='exit 1 when the run misses its realtime goals (missed cycles, '
                         'watchdog trips, lost messages)')
    ap.add_argument('--quiet', action='store_true', help="do not relay the nodes' output")
    hw = ap.add_argument_group('hardware bench (docs/hardware.md)')
    hw.add_argument('--emulate', action='store_true', help='with --hardware: start '
                    '`fiber-align emulate` and use its serial_link and visa_resource')
    hw.add_argument('--slot', type=float, metavar='M', help='--emulate: slot position (m)')
    hw.add_argument('--meter-floor', type=float, default=None, metavar='W',
                    help='--emulate: the PM100 clamps its readings at this floor (W)')
    hw.add_argument('--hold', type=float, default=None, metavar='S',
                    help='--hardware: hold TRACKING this long (s) after the cycles; '
                         'default: until Ctrl-C')
    a = ap.parse_args(argv)
    # the launch arguments' combinations are describe()'s to check; these are bringup's
    if not a.hardware and (a.emulate or a.slot is not None or a.hold is not None):
        ap.error('--emulate, --slot and --hold need --hardware')
    if a.meter_floor is not None and not a.emulate:
        ap.error('--meter-floor needs --hardware --emulate')
    if a.slot is not None and (a.rig or a.array):
        ap.error('--slot is not available with --rig or --array (--seed picks the emulated '
                 'target or chip)')
    if a.emulate and (a.port or a.visa_resource):
        ap.error('--emulate chooses the port and the VISA resource itself')
    if a.cycles is not None and a.cycles < 0:
        ap.error('--cycles must be >= 0, got %d' % a.cycles)
    for path, opt in ((a.trace, '--trace'), (a.summary, '--summary'), (a.record, '--record')):
        if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            ap.error('%s %s: the folder %s does not exist'
                     % (opt, path, os.path.dirname(os.path.abspath(path))))
    return a


def arguments(a, **given):
    """Return the options ``a`` as launch arguments: ``{name: value}`` of ``ARGUMENTS``."""
    out = {name: getattr(a, _dest(option)) for name, (option, _) in OPTIONS.items()}
    out.update(composed=a.composed, **given)
    return out


def graph(a, **given):
    """
    Return ``(graph, source)`` the options ``a`` describe (and ``given`` launch arguments).

    :func:`fiber_align.graph.arguments.describe_run` of :func:`arguments` (the graph as
    ``bringup`` runs it, and the scenario's setpoints), with ``bringup``'s own options
    (``--rate``, ``--no-noise``, ``--storage``, ``-p``) as overrides and ``--duration``.

    :raises GraphError: a bad option, params file or ``-p`` (exit code 2).
    """
    one_axis = not (a.rig or a.station or a.array or a.hardware)
    bad = [opt for attr, opt in ONE_AXIS_OPTIONS if getattr(a, attr) and not one_axis]
    if bad:
        raise GraphError('%s: only on the simulated 1-D graph' % ', '.join(bad))
    ov = {}
    if a.rate:
        ov['/**'] = {'rate_hz': float(a.rate)}
    if a.no_noise:
        ov[PLANT] = {'noise_rms_m': 0.0}
    if a.storage:
        ov[RECORDER] = {'storage': a.storage}
    return describe_run(arguments(a, **given), parse_overrides(a.param, ov), a.duration)
