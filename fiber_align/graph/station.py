# SPDX-License-Identifier: Apache-2.0
"""
The coupled station on the fiber_align graph, described once (pure Python: no rclpy).

The two-axis rig's description (:mod:`fiber_align.graph.rig`: :class:`RigGraph`, its
processes and params merge) with four axes. Under one station namespace (``station``
unless told):

- ``/station/in/x/...``, ``/station/in/y/...``, ``/station/out/x/...``,
  ``/station/out/y/...``: four actuator graphs, each the control nodes of the 1-D graph
  with its own plant (``simulated_actuator``, publishing its true tip position too),
  sensor-noise seed and params sections (``/station/in/x/simulated_actuator``, ...);
- ``/station/simulated_station_optics`` (executable ``simulated_optics``): the four true
  tip positions in, ``optical_power`` (W) out;
- ``/station/station_sequencer`` (executable ``alignment_sequencer``): the four setpoints,
  services ``align``, ``release``, ``switch``;
- ``/station/lifecycle_manager``: activates the four drivers;
- with ``record``: ``/station/bag_recorder``, recording :data:`RECORDED` (every message
  of those topics; a params file can name others); composed, hosted in the station's one
  process, where it takes the axes' messages from the bus instead of DDS.

Layouts as the rig's: composed (default) is one ``control_graph`` process for the four
axes, the optics and the sequencer; multi-process one process per node.

The run's description is the offline one (:mod:`fiber_align.simulation.
station_scenarios`): plant seeds ``4 S`` .. ``4 S + 3`` (in/x, in/y, out/x, out/y),
detector seed ``S + 1000`` and the facets ``random_facets(S)`` for the run seed ``S``.
Lockstep: each plant advances when its drive for sample k arrives; the drives need the
sequencer's setpoints of sample k, which need the four displacements and the power of
sample k, so the four plants and the optics advance in step; the in/x plant publishes
``/clock``.
"""

import os

from fiber_align.graph import description as g
from fiber_align.graph.params import GraphError, LIFECYCLE_MANAGER, PLANT, RECORDER
from fiber_align.graph.rig import in_effect, multi_axis_start, rig_processes, RigGraph
from fiber_align.simulation import station_scenarios as sc

STATION_NAMESPACE = 'station'
AXES = g.STATION_AXES
OPTICS = 'simulated_station_optics'
SEQUENCER = 'station_sequencer'
#: The station's own nodes: name -> executable.
OWN_NODES = {n: g.NODES[n].executable for n in (OPTICS, SEQUENCER)}
MANAGED = tuple('%s/actuator_driver' % a for a in AXES)
#: Topics the recorder records (relative to the station's namespace): per axis what a
#: user analyses (measured position, setpoint, drive), the power and the state.
PER_AXIS_RECORDED = ('displacement', 'setpoint', 'drive_voltage')
RECORDED = tuple('%s/%s' % (a, t) for a in AXES for t in PER_AXIS_RECORDED) + (
    'optical_power', 'alignment_state', '/diagnostics', '/clock')
FACET_KEYS = ('facet_in_x_m', 'facet_in_y_m', 'facet_out_x_m', 'facet_out_y_m')


def build_station(namespace=STATION_NAMESPACE, composed=None, sync_mode='', controller='',
                  params_file='', seed=0, record='', config_directory=None, overrides=None):
    """
    Describe the station for the given launch arguments; return a :class:`RigGraph`.

    :param namespace: the station namespace (``station``).
    :param composed: layout (bool or ``'true'``/``'false'``; ``None``/``''``: default).
    :param sync_mode: ``realtime`` | ``lockstep`` (``''``: as the params files say).
    :param controller: control law of the four axes (``''``: as the params files say).
    :param params_file: a params file merged after ``fiber_align.yaml`` (bare node
        sections apply to every axis, ``in/x/<node>`` to one).
    :param seed: the run seed ``S`` (seeds and facets as offline, module docstring).
    :param record: bag directory (must not exist): adds ``bag_recorder``.
    :param overrides: further ``{node: {name: value}}`` (bringup's options), applied last.
    :raises GraphError: a value is not allowed or a file is missing.
    """
    ns, composed, files, seed, over = multi_axis_start(
        namespace, composed, config_directory, OWN_NODES, params_file, overrides, seed,
        sync_mode, controller)
    seeds = sc.run_seeds(seed)
    over[PLANT] = {'optical_power_every': 0, 'tip_position_every': 1}
    for i, a in enumerate(AXES):
        over['%s/%s' % (a, PLANT)] = {'seed': seeds['plant'] + i, 'publish_clock': i == 0}
    over[OPTICS] = dict(zip(FACET_KEYS, sc.random_facets(seed)), seed=seeds['detector'])
    over[LIFECYCLE_MANAGER] = {'managed_nodes': list(MANAGED)}
    if record:
        record = os.path.abspath(record)
        if os.path.exists(record):
            raise GraphError('record %s already exists: give a new bag directory' % record)
        over[RECORDER] = {'output': record, 'topics': list(RECORDED)}
        if not composed:
            # realtime per-sample topics are volatile: the clock waits for the recorder
            # (composed, it reads them in-process from before the first sample)
            over[PLANT]['start_after_reader'] = '/%s/%s' % (ns, RECORDER) if ns else RECORDER
    over = g.add_overrides(over, overrides)
    sync, law = in_effect(files, over)
    return RigGraph(namespace=ns, composed=composed, sync_mode=sync, controller=law,
                    scenario='station', record=record or '',
                    processes=rig_processes(ns, composed, AXES, OWN_NODES, 'station',
                                            bool(record)),
                    params_files=tuple(files), overrides=over, remappings=g.REMAPPINGS,
                    managed_nodes=MANAGED, seed=seed, axes=AXES, own_nodes=tuple(OWN_NODES))
