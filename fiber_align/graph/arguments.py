# SPDX-License-Identifier: Apache-2.0
"""
From launch arguments to a graph, once: :func:`describe` (pure: no rclpy).

``ros2 launch fiber_align fiber_align.launch.py name:=value ...`` and ``bringup`` (its
options turned into these arguments, :func:`fiber_align.bringup.cli.arguments`) both
call :func:`describe` (``bringup`` through :func:`describe_run`: the plants held, a 1-D
scenario ended by ``bringup``). The machine (the 1-D graph, the two-axis rig, the
coupled station, the fiber array, the sensorless hardware bench, the rig on hardware) is
chosen by data: the ``rig``, ``station``, ``array`` and ``hardware`` switches select a row of
:data:`MACHINES`, which names its builder, its default namespace and the arguments it
takes; an argument given to a machine that does not take it is refused in one line.
``live`` adds the live view to any of them (:func:`fiber_align.graph.live.with_live`),
``catalog`` the run catalogue's node (:func:`fiber_align.graph.catalog.with_catalog`; on
by default), ``snapshots`` the flight recorder (:func:`fiber_align.graph.snapshots.
with_snapshots`).
"""

from dataclasses import dataclass
from typing import Callable, Tuple

from fiber_align.graph.array import ARRAY_NAMESPACE, build_array
from fiber_align.graph.catalog import with_catalog
from fiber_align.graph.description import build, parse_bool
from fiber_align.graph.hardware import build_hardware
from fiber_align.graph.hardware_rig import build_hardware_array, build_hardware_rig
from fiber_align.graph.live import check_endpoint, live_settings, with_live
from fiber_align.graph.params import GraphError, PLANT, SCENARIO_RUNNER
from fiber_align.control.factory import CONTROLLERS
from fiber_align.graph.params import SYNC_MODES
from fiber_align.graph.refusals import check_graph
from fiber_align.graph.registry import DEFAULT_COMPOSED, SCENARIOS
from fiber_align.graph.rig import build_rig, check_seed, RIG_NAMESPACE
from fiber_align.graph.snapshots import with_snapshots
from fiber_align.graph.station import build_station, STATION_NAMESPACE
from fiber_align.simulation.setpoints import setpoint_range, Source

#: name, default, description, choices (``None``: any value): the launch file declares
#: them, ``bringup``'s options are named after them.
ARGUMENTS = (
    ('namespace', '', 'namespace of every node ("" = none; the rig: rig, the station: '
     'station, the array: array)', None),
    ('composed', str(DEFAULT_COMPOSED).lower(),
     'true: the control nodes in one control_graph process; false: one process per node',
     ['true', 'false']),
    ('sync_mode', '', 'sample clock ("" = as the params files say: realtime)',
     [''] + list(SYNC_MODES)),
    ('controller', '', 'control law ("" = as the params files say: composite)',
     [''] + list(CONTROLLERS)),
    ('params_file', '', 'params file applied after config/fiber_align.yaml', None),
    ('model_file', '', 'PI model params file for hysteresis_compensator ("" = inline)',
     None),
    ('record', '', 'bag directory to record into (must not exist; "" = no recording)', None),
    ('scenario', '', 'setpoint scenario of scenario_runner ("" = as the params files say: '
     'none, the graph waits for setpoints)', [''] + list(SCENARIOS)),
    ('rig', 'false', 'true: the two-axis rig (/rig/x, /rig/y, optics, 2-D sequencer) '
     'instead of the 1-D graph', ['true', 'false']),
    ('station', 'false', 'true: the coupled station (/station/in/x .. /station/out/y, the '
     "chip's optics, the station sequencer) instead of the 1-D graph", ['true', 'false']),
    ('array', 'false', 'true: the fiber array (/array/x, /array/y_left, /array/y_right, '
     "the array's optics, the array sequencer) instead of the 1-D graph", ['true', 'false']),
    ('seed', '', 'rig, station, array: run seed (plant, detector seeds and target, facets '
     'or chip, as the offline align2d, station and array; "" = 0); the 1-D graph: the '
     'plant\'s noise seed '
     '("" = config/plant.yaml)', None),
    ('hardware', 'false', 'true: the sensorless bench (MDT693B + PM100) instead of the '
     'simulated actuator', ['true', 'false']),
    ('port', '', 'hardware: MDT693B serial device ("" = config/hardware.yaml)', None),
    ('visa_resource', '', 'hardware: PM100 VISA resource ("" = config/hardware.yaml; the '
     "array: A,B, channel 1's meter and channel N's)", None),
    ('live', 'false', 'true: the Foxglove live view (ws://live_host:live_port, '
     'docs/live_view.md)', ['true', 'false']),
    ('live_port', '', 'live view TCP port ("" = config/live_view.yaml: 8765)', None),
    ('live_host', '', 'live view address ("" = config/live_view.yaml: 127.0.0.1)', None),
    ('catalog', '', 'run catalogue: none, default (SQLite $ROS_HOME/fiber_align/catalog.db), '
     'a SQLite path or postgresql://... ("" = config/records.yaml: default; '
     'docs/records.md)', None),
    ('snapshots', '', 'flight recorder: folder of the snapshot bags (the last 10 s and the '
     'next 2 s of every recorded topic on a fault, a hold, a watchdog trip, a missed cycle '
     'goal or the recorder\'s ~/snapshot service; without record: the recorder with its '
     'bag off; "" = none; docs/records.md)', None),
)
#: The switches that choose the machine, in the order of :data:`MACHINES`' keys.
SWITCHES = ('rig', 'station', 'array', 'hardware')
#: The live view's arguments (every machine), in :func:`with_live`'s order.
LIVE_ARGS = ('live', 'live_port', 'live_host')
#: The run catalogue's argument (every machine, :func:`with_catalog`).
CATALOG_ARGS = ('catalog', 'snapshots')
#: Every machine's arguments (its builder's keywords, ``seed`` aside).
COMMON = ('namespace', 'composed', 'params_file')


@dataclass(frozen=True)
class Machine:
    """
    One graph the arguments can choose.

    :ivar build: its builder (keywords: :data:`COMMON`, :attr:`takes`, ``overrides``).
    :ivar takes: the other arguments it takes (given ones it does not: refused).
    :ivar chosen: how a user chose it, for the refusal (``rig:=true``).
    :ivar namespace: its namespace when none is given.
    :ivar seed: what ``seed`` is to it: ``'run'`` (the run seed), ``'plant'`` (the 1-D
        plant's noise seed, when given) or ``''`` (nothing of the graph's: ``bringup
        --hardware --emulate`` gives it to the emulator).
    """

    build: Callable
    takes: Tuple[str, ...]
    chosen: str
    namespace: str = ''
    seed: str = ''


#: The arguments of the simulated loop, and of the devices.
SIMULATED = ('sync_mode', 'controller')
HARDWARE = ('port', 'visa_resource')
#: (rig, station, array, hardware) -> the machine they choose.
MACHINES = {
    (False, False, False, False): Machine(build, SIMULATED + ('model_file', 'record',
                                                              'scenario'),
                                          'the simulated 1-D graph', seed='plant'),
    (True, False, False, False): Machine(build_rig, SIMULATED, 'rig:=true', RIG_NAMESPACE,
                                         'run'),
    (False, True, False, False): Machine(build_station, SIMULATED + ('record',),
                                         'station:=true', STATION_NAMESPACE, 'run'),
    (False, False, True, False): Machine(build_array, SIMULATED + ('record',), 'array:=true',
                                         ARRAY_NAMESPACE, 'run'),
    (False, False, False, True): Machine(build_hardware, HARDWARE + ('model_file', 'record'),
                                         'hardware:=true'),
    (True, False, False, True): Machine(build_hardware_rig, HARDWARE,
                                        'rig:=true hardware:=true', RIG_NAMESPACE),
    (False, False, True, True): Machine(build_hardware_array, HARDWARE,
                                        'array:=true hardware:=true', ARRAY_NAMESPACE),
}


def machine(arguments):
    """Return the :class:`Machine` the switches of ``arguments`` choose, or raise."""
    on = tuple(parse_bool(k, arguments.get(k) or False) for k in SWITCHES)
    if on in MACHINES:
        return MACHINES[on]
    main = 'array' if on[SWITCHES.index('array')] else 'station'
    return _refuse(['%s:=true' % k for k, v in zip(SWITCHES, on) if v and k != main],
                   main + ':=true')


def _refuse(given, chosen):
    if given == [a for a in given if a in HARDWARE]:
        raise GraphError('%s: only with hardware:=true' % ', '.join(given))
    raise GraphError('%s: not available with %s' % (', '.join(given), chosen))


def describe(arguments, overrides=None):
    """
    Return the graph that launch arguments describe: any ``Graph`` of ``graph/``.

    :param arguments: ``{name: value}`` of :data:`ARGUMENTS` (strings as launch gives
        them, or Python values; a missing one is its default, ``''`` "as the files say").
    :param overrides: ``{node or '/**': {name: value}}`` applied last (``bringup -p`` and
        its options), checked against the shipped files.
    :raises GraphError: a bad value (out of the range its node declares, a drive limit
        beyond the field limits or the amplifier's:
        :func:`~fiber_align.graph.refusals.check_graph`), an argument the machine does
        not take, a live view port in use (one line, before any process starts).
    """
    args = {k: v for k, v in dict(arguments).items() if v not in (None, '', (), [])}
    m = machine(args)
    given = [k for k in args if k not in COMMON + m.takes + SWITCHES + LIVE_ARGS + ('seed',)
             + CATALOG_ARGS]
    if given:
        _refuse(given, m.chosen)
    over = dict(overrides or {})
    kw = {k: args[k] for k in COMMON + m.takes if k in args}
    kw['namespace'] = kw.get('namespace') or m.namespace
    seed = args.get('seed')
    if m.seed == 'run':
        kw['seed'] = check_seed(seed if seed is not None else 0)
    elif m.seed == 'plant' and seed is not None:
        over[PLANT] = dict({'seed': check_seed(seed)}, **over.get(PLANT, {}))
    g = with_live(m.build(overrides=over, **kw), *[args.get(k, '') for k in LIVE_ARGS])
    g = with_snapshots(g, args.get('snapshots', ''))
    # last: its parameters are the whole graph's; the live view does not show its topics
    g = with_catalog(g, args.get('catalog', ''), m.build in (build_hardware, build_hardware_rig,
                                                             build_hardware_array))
    check_graph(g)              # every declared range, the drive limits: before any start
    served = live_settings(g)
    if served:                  # a port in use: one line before any process starts
        check_endpoint(*served)
    return g


def describe_run(arguments, overrides=None, duration_s=None):
    """
    Return ``(graph, source)``: the graph of :func:`describe` as ``bringup`` runs it.

    ``bringup`` starts the simulated plants itself once the graph is connected (their
    ``autostart`` false; the 1-D graph without a scenario starts as under launch) and ends
    a 1-D scenario itself: its runner neither ends the graph nor waits for the recorder,
    and runs ``duration_s`` (s; ``None``: as its params say, else the scenario's length).

    :returns: the graph and the scenario's setpoints
        (:class:`~fiber_align.simulation.setpoints.Source`; ``None``: no scenario runner).
    """
    ov = dict(overrides or {})
    built = machine(arguments).build
    held = {PLANT: dict(ov.get(PLANT, {}), autostart=False)}
    if built in (build_rig, build_station, build_array):
        return describe(arguments, dict(ov, **held)), None
    g = describe(arguments, ov)
    if built is not build or g.scenario == 'none':
        return g, None
    ov.update(held)
    src = None
    if SCENARIO_RUNNER in g.nodes:
        sp = g.node_params(SCENARIO_RUNNER)
        src = Source(g.scenario, *setpoint_range(sp['setpoint_min_m'], sp['setpoint_max_m'],
                                                 sp['reach_m']))
        dur = duration_s or float(sp['duration_s']) or float(src.sc.duration_s)
        ov[SCENARIO_RUNNER] = dict(ov.get(SCENARIO_RUNNER, {}), exit_when_done=False,
                                   wait_for_recorder=False, duration_s=float(dur))
    return describe(dict(arguments, scenario=g.scenario), ov), src
