# SPDX-License-Identifier: Apache-2.0
"""
``bringup``'s command line: options, their checks, and the graph they describe.

The options map onto the arguments of :mod:`fiber_align.graph` (``build``,
``build_rig``, ``build_hardware``: the launch file's), and the rest onto parameter
overrides of the description; bringup merges nothing itself.
"""

import argparse
import math
import os
import sys

import yaml

from fiber_align.config import ConfigError
from fiber_align.graph import description as gd, rig as gr, station as gs
from fiber_align.graph.description import NODES
from fiber_align.graph.live import check_endpoint, live_settings, with_live
from fiber_align.graph.params import GraphError, PLANT, RECORDER, SCENARIO_RUNNER
from fiber_align.nodes.scenario_runner import setpoint_range, Source
from fiber_align.simulation.scenarios import TRACKING as TRACKING_SCENARIOS  # noqa: F401

#: bringup options of the 1-D graph only: (attribute, option); refused with ``--rig``.
ONE_AXIS_OPTIONS = (('scenario', '--scenario'), ('model', '--model'), ('rate', '--rate'),
                    ('no_noise', '--no-noise'), ('record', '--record'),
                    ('storage', '--storage'))
#: What the scenario runner publishes in the open-loop experiment (it drives the driver).
OPEN_LOOP = ('feedforward_voltage', 'feedback_voltage')


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
        return gd.check_namespace(text)
    except GraphError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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
    ap.add_argument('--scenario', choices=gd.SCENARIOS, default=None,
                    help='scenario to run (default: scenario_runner.scenario of '
                         'config/scenario.yaml, as ros2 launch)')
    ap.add_argument('--rig', action='store_true',
                    help='the two-axis rig (/rig/x, /rig/y, optics, 2-D sequencer) running '
                         'align2d; lockstep: compared with the offline run (--seed: the '
                         "run seed, as fiber-align simulate --scenario align2d's)")
    ap.add_argument('--station', action='store_true',
                    help='the coupled station (/station/in/x .. /station/out/y, optics, '
                         'station sequencer): align as --rig; lockstep: compared with '
                         "fiber-align simulate --scenario station's run (--seed)")
    ap.add_argument('--duration', type=_positive(float, '--duration'), default=None,
                    help="scenario length (s of sample time; default: the scenario's); "
                    '--rig, --station: hold TRACKING this long after the cycles')
    ap.add_argument('--sync', choices=('realtime', 'lockstep'), default=None,
                    help='sample clock (default: sync_mode of fiber_align.yaml)')
    ap.add_argument('--controller', choices=gd.CONTROLLERS, default=None,
                    help='control law (default: controller of fiber_align.yaml)')
    ap.add_argument('--model', metavar='FILE', default=None,
                    help='PI model params file for the compensator (e.g. from fiber-align '
                         'identify, or config/hysteresis_paper.yaml)')
    ap.add_argument('--rate', type=_positive(float, '--rate'), default=None,
                    help='control rate (Hz)')
    ap.add_argument('--seed', type=int, default=None, help='plant sensor-noise seed')
    ap.add_argument('--no-noise', action='store_true', help='sensor noise off')
    ap.add_argument('--cycles', type=int, default=None,
                    help='align: switch off/on cycles after TRACKING (default 5); --rig: '
                    'release / align cycles after the first TRACKING (default 0)')
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
                    'MDT693B + PM100 (no simulated plant): align, --cycles, hold; with '
                    '--rig: both axes on one MDT693B (config/hardware_rig.yaml)')
    hw.add_argument('--emulate', action='store_true', help='with --hardware: start '
                    '`fiber-align emulate` and use its serial_link and visa_resource')
    hw.add_argument('--port', help='MDT693B serial device (default: config/hardware.yaml)')
    hw.add_argument('--visa-resource', help='PM100 VISA resource (default: hardware.yaml)')
    hw.add_argument('--slot', type=float, metavar='M', help='--emulate: slot position (m)')
    hw.add_argument('--hold', type=float, default=None, metavar='S',
                    help='--hardware: hold TRACKING this long (s) after the cycles; '
                         'default: until Ctrl-C')
    lv = ap.add_argument_group('live view (docs/live_view.md)')
    lv.add_argument('--live', action='store_true', help='serve the graph to Foxglove '
                    '(ws://HOST:PORT; the live_view process)')
    lv.add_argument('--live-port', type=int, default=None, metavar='PORT',
                    help='--live: TCP port (default: config/live_view.yaml, 8765)')
    lv.add_argument('--live-host', default=None, metavar='HOST',
                    help='--live: address (default: config/live_view.yaml, 127.0.0.1)')
    a = ap.parse_args(argv)
    if a.station and (a.rig or a.hardware):
        ap.error('--station is a graph of its own: not with --rig or --hardware')
    if not a.live and (a.live_port is not None or a.live_host is not None):
        ap.error('--live-port and --live-host need --live')
    if not a.hardware and (a.emulate or a.port or a.visa_resource or a.slot is not None
                           or a.hold is not None):
        ap.error('--emulate, --port, --visa-resource, --slot and --hold need --hardware')
    if a.hardware and a.rig and (a.slot is not None or a.record or a.model):
        ap.error('--slot, --record and --model are not available with --rig --hardware '
                 '(--seed picks the emulated target; the models are in hardware_rig.yaml)')
    if a.emulate and (a.port or a.visa_resource):
        ap.error('--emulate chooses the port and the VISA resource itself')
    if a.cycles is not None and a.cycles < 0:
        ap.error('--cycles must be >= 0, got %d' % a.cycles)
    for path, opt in ((a.trace, '--trace'), (a.summary, '--summary'), (a.record, '--record')):
        if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            ap.error('%s %s: the folder %s does not exist'
                     % (opt, path, os.path.dirname(os.path.abspath(path))))
    return a


def describe(a):
    """
    Return ``(graph, source)`` of the 1-D graph the options ``a`` describe.

    The description's :func:`~fiber_align.graph.description.build` with the launch
    arguments of the options; with a scenario the harness holds the plant until the
    graph is connected (``autostart`` false) and ends the run itself (the runner's
    ``exit_when_done`` false, ``duration_s`` set). ``source``: the scenario runner's
    setpoints (:class:`~fiber_align.nodes.scenario_runner.Source`) or ``None``.

    :raises GraphError: a bad option, params file or ``-p`` (exit code 2).
    """
    ov = parse_params(a.param, {})
    plant = {} if a.seed is None else {'seed': int(a.seed)}
    if a.no_noise:
        plant['noise_rms_m'] = 0.0
    if a.rate:
        ov.setdefault('/**', {})['rate_hz'] = float(a.rate)
    if a.storage:
        ov.setdefault(RECORDER, {})['storage'] = a.storage
    kw = dict(namespace=a.namespace, composed=a.composed, sync_mode=a.sync or '',
              controller=a.controller or '', params_file=a.params_file,
              model_file=a.model or '', record=a.record or '')
    g = gd.build(scenario=a.scenario or '', overrides=dict(ov, **{PLANT: plant}) if plant
                 else ov, **kw)
    if g.scenario == 'none':
        return live(a, g), None
    plant['autostart'] = False
    ov[PLANT] = dict(ov.get(PLANT, {}), **plant)
    src = None
    if SCENARIO_RUNNER in g.nodes:
        sp = g.node_params(SCENARIO_RUNNER)
        src = Source(g.scenario, *setpoint_range(sp['setpoint_min_m'], sp['setpoint_max_m'],
                                                 sp['reach_m']))
        dur = a.duration or float(sp['duration_s']) or float(src.sc.duration_s)
        ov[SCENARIO_RUNNER] = dict(ov.get(SCENARIO_RUNNER, {}), exit_when_done=False,
                                   wait_for_recorder=False, duration_s=float(dur))
    return live(a, gd.build(scenario=g.scenario, overrides=ov, **kw)), src


def live(a, graph):
    """
    Return ``graph`` with the live view when ``--live`` (:func:`fiber_align.graph.live.with_live`).

    :raises GraphError: a bad ``--live-port``/``--live-host``, or that port in use.
    """
    g = with_live(graph, a.live, '' if a.live_port is None else a.live_port,
                  a.live_host or '')
    served = live_settings(g)
    if served:
        check_endpoint(*served)
    return g


def expected_endpoints(graph, observed=(), recorded=()):
    """
    Return ``{topic: (publishers, subscribers)}`` (at least) the running graph must have.

    From the node registry (:data:`fiber_align.graph.description.NODES`): the topics its
    nodes publish and read, only those some node, the observer or the recorder reads. A
    reader hosted in one process with the topic's publisher reads it in-process
    (``LocalBus``), not as a DDS subscription.

    :param graph: a 1-D :class:`~fiber_align.graph.description.Graph`.
    :param observed: the topics the observer subscribes to.
    :param recorded: the topics the recorder subscribes to (``topics``; empty: none).
    """
    def publishes(node):
        if node == SCENARIO_RUNNER:
            return OPEN_LOOP if graph.scenario == 'hysteresis-experiment' else ('setpoint',)
        return NODES[node].publishes if node in NODES else ()
    pubs, subs = {}, {t: 1 for t in observed}
    for p in graph.processes:
        own = {t for n in p.nodes for t in publishes(n)}
        for n in p.nodes:
            for t in publishes(n):
                pubs[t] = pubs.get(t, 0) + 1
            for t in NODES[n].subscribes if n in NODES else ():
                if not (len(p.nodes) > 1 and t in own):
                    subs[t] = subs.get(t, 0) + 1
    out = {t: (pubs.get(t, 0), n) for t, n in subs.items()}
    if graph.sync_mode == 'lockstep':
        out['/clock'] = (1, 0)
    recorded = {t.lstrip('/') for t in recorded}
    return {k: (p, s + (1 if p and k.lstrip('/') in recorded else 0))
            for k, (p, s) in out.items()}


def describe_rig(a):
    """
    Return the rig's :class:`~fiber_align.graph.rig.RigGraph` for the options ``a``.

    The plants are held (``autostart`` false) until both drivers are active.

    :raises GraphError: a bad option (exit code 2).
    """
    bad = [opt for attr, opt in ONE_AXIS_OPTIONS if getattr(a, attr, None) not in (None, False)]
    if bad:
        raise GraphError('%s: not available with --rig' % ', '.join(bad))
    ov = parse_params(a.param, {PLANT: {'autostart': False}})
    return live(a, gr.build_rig(namespace=a.namespace or gr.RIG_NAMESPACE,
                                composed=a.composed, sync_mode=a.sync or '',
                                controller=a.controller or '', seed=int(a.seed or 0),
                                params_file=a.params_file, overrides=ov))


def describe_station(a):
    """
    Return the station's :class:`~fiber_align.graph.rig.RigGraph` for the options ``a``.

    As :func:`describe_rig`; ``--record`` (and ``--storage``) record the station's topics.

    :raises GraphError: a bad option (exit code 2).
    """
    bad = [opt for attr, opt in ONE_AXIS_OPTIONS if attr not in ('record', 'storage')
           and getattr(a, attr, None) not in (None, False)]
    if bad:
        raise GraphError('%s: not available with --station' % ', '.join(bad))
    ov = {PLANT: {'autostart': False}}
    if a.storage:
        ov[RECORDER] = {'storage': a.storage}
    ov = parse_params(a.param, ov)
    return live(a, gs.build_station(namespace=a.namespace or gs.STATION_NAMESPACE,
                                    composed=a.composed, sync_mode=a.sync or '',
                                    controller=a.controller or '', seed=int(a.seed or 0),
                                    record=a.record or '', params_file=a.params_file,
                                    overrides=ov))


def parse_params(items, ov):
    """
    Return ``ov`` (``{node or '/**': {name: value}}``) updated by ``-p`` items.

    :param items: ``NODE:NAME:=VALUE`` strings (``NODE`` ``**`` = all nodes; VALUE YAML).
    :raises ConfigError: an item that is not ``NODE:NAME:=VALUE`` or not YAML.
    """
    # NODE may be <axis>/<node> (the rig): the description checks the names
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
