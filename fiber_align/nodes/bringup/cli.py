# SPDX-License-Identifier: Apache-2.0
"""``bringup``'s command line: options, their checks, the parameter overrides."""

import argparse
import math
import os
import re
import sys

import yaml

from fiber_align.config import ConfigError

SCENARIOS = ('none', 'step', 'sine', 'triangle', 'staircase', 'hysteresis-experiment',
             'align')
TRACKING_SCENARIOS = ('step', 'sine', 'triangle', 'staircase')
#: controller names, as in ``fiber-align simulate``
CONTROLLERS = ('composite', 'composite-pid', 'fuzzy', 'pid', 'feedforward', 'open-loop')
_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$')


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
    ns = text.strip('/')
    if ns and not _NAME.match(ns):
        raise argparse.ArgumentTypeError(
            'namespace %r: letters, digits and _ separated by /, each part starting with '
            'a letter' % text)
    return ns


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``bringup: error: ...``), exit 2."""

    def error(self, message):
        """Print one line naming what is wrong and what is allowed; exit 2."""
        self.exit(2, '%s: error: %s\n' % (self.prog, message))


def parse_args(argv):
    """Parse the command line (ROS arguments after ``--ros-args`` are ignored)."""
    if argv is None:
        argv = sys.argv[1:]
    if '--ros-args' in argv:
        argv = argv[:argv.index('--ros-args')]
    ap = _Parser(prog='bringup', description='Start the fiber_align graph, run a scenario, '
                 'record, stop, summarise.')
    ap.add_argument('--scenario', choices=SCENARIOS, default=None,
                    help='scenario to run (default: bringup.scenario of fiber_align.yaml)')
    ap.add_argument('--rig', action='store_true',
                    help='the two-axis rig (/rig/x, /rig/y, optics, 2-D sequencer) running '
                         'align2d; lockstep: compared with the offline run (--seed: the '
                         "run seed, as fiber-align simulate --scenario align2d's)")
    ap.add_argument('--duration', type=_positive(float, '--duration'), default=None,
                    help="scenario length (s of sample time; default: the scenario's)")
    ap.add_argument('--sync', choices=('realtime', 'lockstep'), default=None,
                    help='sample clock (default: sync_mode of fiber_align.yaml)')
    ap.add_argument('--controller', choices=CONTROLLERS, default='composite')
    ap.add_argument('--model', metavar='FILE', default=None,
                    help='PI model params file for the compensator (e.g. from fiber-align '
                         'identify, or config/hysteresis_paper.yaml)')
    ap.add_argument('--rate', type=_positive(float, '--rate'), default=None,
                    help='control rate (Hz)')
    ap.add_argument('--seed', type=int, default=None, help='plant sensor-noise seed')
    ap.add_argument('--no-noise', action='store_true', help='sensor noise off')
    ap.add_argument('--cycles', type=int, default=None,
                    help='align: switch off/on cycles after TRACKING (default 5)')
    ap.add_argument('--record', metavar='DIR', default=None, help='record a bag into DIR')
    ap.add_argument('--storage', choices=('mcap', 'sqlite3'), default=None)
    layout = ap.add_mutually_exclusive_group()
    layout.add_argument('--composed', dest='composed', action='store_true', default=None,
                        help='the control nodes in one process (control_graph; default)')
    layout.add_argument('--multi-process', dest='composed', action='store_false',
                        help='one process per node')
    ap.add_argument('--namespace', type=_namespace, default='',
                    help='namespace of the whole graph')
    ap.add_argument('--params-file', action='append', default=[],
                    help='extra params file (applied after config/fiber_align.yaml)')
    ap.add_argument('-p', '--param', action='append', default=[], metavar='NODE:NAME:=VALUE',
                    help='override one parameter (NODE may be **)')
    ap.add_argument('--trace', metavar='CSV', help='write t_s,r_m,y_m of every sample')
    ap.add_argument('--summary', metavar='JSON', help='write the summary as JSON')
    ap.add_argument('--strict', action='store_true',
                    help='exit 1 when the run misses its realtime goals (missed cycles, '
                         'watchdog trips, lost messages)')
    ap.add_argument('--quiet', action='store_true', help="do not relay the nodes' output")
    hw = ap.add_argument_group('hardware bench (docs/hardware.md)')
    hw.add_argument('--hardware', action='store_true', help='the sensorless graph on an '
                    'MDT693B + PM100 (no simulated plant): align, --cycles, hold')
    hw.add_argument('--emulate', action='store_true', help='with --hardware: start '
                    '`fiber-align emulate` and use its serial_link and visa_resource')
    hw.add_argument('--port', help='MDT693B serial device (default: config/hardware.yaml)')
    hw.add_argument('--visa-resource', help='PM100 VISA resource (default: hardware.yaml)')
    hw.add_argument('--slot', type=float, metavar='M', help='--emulate: slot position (m)')
    hw.add_argument('--hold', type=float, default=None, metavar='S',
                    help='--hardware: hold TRACKING this long (s) after the cycles; '
                         'default: until Ctrl-C')
    a = ap.parse_args(argv)
    if not a.hardware and (a.emulate or a.port or a.visa_resource or a.slot is not None
                           or a.hold is not None):
        ap.error('--emulate, --port, --visa-resource, --slot and --hold need --hardware')
    if a.hardware and a.rig:
        ap.error('--hardware and --rig: choose one')
    if a.emulate and (a.port or a.visa_resource):
        ap.error('--emulate chooses the port and the VISA resource itself')
    if a.cycles is not None and a.cycles < 0:
        ap.error('--cycles must be >= 0, got %d' % a.cycles)
    for path, opt in ((a.trace, '--trace'), (a.summary, '--summary')):
        if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            ap.error('%s %s: the folder %s does not exist'
                     % (opt, path, os.path.dirname(path) or '.'))
    if a.record and os.path.exists(a.record):
        ap.error('--record %s exists already; choose a new bag directory' % a.record)
    if a.record and not os.path.isdir(os.path.dirname(os.path.abspath(a.record))):
        ap.error('--record %s: the folder %s does not exist'
                 % (a.record, os.path.dirname(os.path.abspath(a.record))))
    if a.model and not os.path.isfile(a.model):
        ap.error('--model %s: no such file' % a.model)
    return a


def param_overrides(args, sync):
    """
    Return ``{node or '/**': {name: value}}`` of the command line.

    :raises ConfigError: a ``-p`` that is not ``NODE:NAME:=VALUE``.
    """
    ov = {'/**': {'sync_mode': sync, 'controller': args.controller},
          'simulated_actuator': {'autostart': False}}
    if args.seed is not None:
        ov['simulated_actuator']['seed'] = int(args.seed)
    if args.no_noise:
        ov['simulated_actuator']['noise_rms_m'] = 0.0
    if args.model:
        ov['hysteresis_compensator'] = {'model_file': os.path.abspath(args.model)}
    return parse_params(args.param, ov)


def parse_params(items, ov):
    """
    Return ``ov`` (``{node or '/**': {name: value}}``) updated by ``-p`` items.

    :param items: ``NODE:NAME:=VALUE`` strings (``NODE`` ``**`` = all nodes; VALUE YAML).
    :raises ConfigError: an item that is not ``NODE:NAME:=VALUE`` or not YAML.
    """
    for item in items:
        node, sep1, rest = item.partition(':')
        name, sep2, value = rest.partition(':=')
        if not (node and sep1 and name and sep2):
            raise ConfigError('-p wants NODE:NAME:=VALUE, got %r' % item)
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            raise ConfigError('-p %s: %r is not a YAML value' % (item, value)) from None
        ov.setdefault('/**' if node in ('**', '/**') else node, {})[name] = parsed
    return ov
