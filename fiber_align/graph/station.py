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

from fiber_align.graph.params import STATION_OPTICS as OPTICS, STATION_SEQUENCER as SEQUENCER
from fiber_align.graph.registry import NODES, STATION_AXES
from fiber_align.graph.rig import build_axes, Machine
from fiber_align.simulation import station_scenarios as sc

STATION_NAMESPACE = 'station'
AXES = STATION_AXES
#: The station's own nodes: name -> executable.
OWN_NODES = {n: NODES[n].executable for n in (OPTICS, SEQUENCER)}
#: Topics the recorder records (relative to the station's namespace): per axis what a
#: user analyses (measured position, setpoint, drive), the power and the state.
PER_AXIS_RECORDED = ('displacement', 'reference', 'drive_voltage')
RECORDED = tuple('%s/%s' % (a, t) for a in AXES for t in PER_AXIS_RECORDED) + (
    'optical_power', 'alignment_state', '/diagnostics', '/clock')
#: The per-sample streams: :class:`~fiber_align.simulation.station_scenarios.StationBench`'s
#: trace columns, measured and setpoint per axis, and the power.
STREAMS = tuple(zip(sc.StationBench.MEASURED, ['%s/displacement' % a for a in AXES])) + tuple(
    zip(sc.StationBench.SETPOINT, ['%s/reference' % a for a in AXES])) + (('p', 'optical_power'),)
FACET_KEYS = ('facet_in_x_m', 'facet_in_y_m', 'facet_out_x_m', 'facet_out_y_m')
#: The station: plant seeds ``4 S`` .. ``4 S + 3``, detector seed ``S + 1000``, the
#: facets ``random_facets(S)`` (:mod:`fiber_align.simulation.station_scenarios`).
STATION = Machine(
    'station', STATION_NAMESPACE, AXES, OWN_NODES,
    lambda seed: tuple(sc.run_seeds(seed)['plant'] + i for i in range(len(AXES))),
    lambda seed: {OPTICS: dict(zip(FACET_KEYS, sc.random_facets(seed)),
                               seed=sc.run_seeds(seed)['detector'])}, RECORDED, STREAMS)


def build_station(namespace=STATION_NAMESPACE, composed=None, sync_mode='', controller='',
                  params_file='', seed=0, record='', config_directory=None, overrides=None):
    """Describe the station for the launch arguments (:func:`~.rig.build_axes`, STATION)."""
    return build_axes(STATION, namespace, composed, sync_mode, controller, params_file,
                      seed, record, config_directory, overrides)
