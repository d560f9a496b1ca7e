# SPDX-License-Identifier: Apache-2.0
"""
The fiber array on the fiber_align graph, described once (pure Python: no rclpy).

The two-axis rig's description (:mod:`fiber_align.graph.rig`: :class:`RigGraph`, its
processes and params merge) with the array's three actuators. Under one namespace
(``array`` unless told):

- ``/array/x/...``, ``/array/y_left/...``, ``/array/y_right/...``: three actuator graphs,
  each the control nodes of the 1-D graph with its own plant (publishing its true tip
  position too), sensor-noise seed and params sections;
- ``/array/simulated_array_optics`` (executable ``simulated_optics``, ``link: array``):
  the three true tip positions in, the outer channels' readings ``optical_power``
  (channel 1) and ``optical_power_n`` (channel N) out (W), and ``array_model`` (the
  pose and every channel's coupling the model predicts, every ``model_period_s``);
- ``/array/array_sequencer`` (executable ``alignment_sequencer``, ``machine: array``):
  the three setpoints, services ``align``, ``release``, ``switch``;
- ``/array/lifecycle_manager``: activates the three drivers;
- with ``record``: ``/array/bag_recorder``, recording :data:`RECORDED`.

The run's description is the offline one (:mod:`fiber_align.simulation.array_scenarios`):
plant seeds ``3 S`` .. ``3 S + 2`` (x, y_left, y_right), detector seeds ``S + 1000`` and
``S + 1001``, the chip's pose ``random_chip(S)`` and ``layout_seed`` ``S`` for the run
seed ``S``. Lockstep: the three plants and the optics advance in step; the x plant
publishes ``/clock``.
"""

from fiber_align.graph.params import ARRAY_OPTICS as OPTICS, ARRAY_SEQUENCER as SEQUENCER
from fiber_align.graph.registry import ARRAY_AXES, ARRAY_POWERS, NODES
from fiber_align.graph.rig import build_axes, Machine
from fiber_align.simulation import array_scenarios as sc

ARRAY_NAMESPACE = 'array'
AXES = ARRAY_AXES
#: The array's own nodes: name -> executable.
OWN_NODES = {n: NODES[n].executable for n in (OPTICS, SEQUENCER)}
#: Topics the recorder records (relative to the array's namespace).
PER_AXIS_RECORDED = ('displacement', 'setpoint', 'drive_voltage')
RECORDED = tuple('%s/%s' % (a, t) for a in AXES for t in PER_AXIS_RECORDED) + \
    ARRAY_POWERS + ('array_model', 'alignment_state', '/diagnostics', '/clock')
#: The per-sample streams: :class:`~fiber_align.simulation.array_scenarios.ArrayBench`'s
#: trace columns, measured and setpoint per actuator, the outer channels' readings.
STREAMS = tuple(zip(sc.ArrayBench.MEASURED, ['%s/displacement' % a for a in AXES])) + tuple(
    zip(sc.ArrayBench.SETPOINT, ['%s/reference' % a for a in AXES])) + tuple(
    zip(sc.ArrayBench.POWERS, ARRAY_POWERS))
CHIP_KEYS = ('chip_x_m', 'chip_y_m', 'chip_roll_rad')


def _seeded(seed):
    return {OPTICS: dict(zip(CHIP_KEYS, sc.random_chip(seed)), layout_seed=int(seed),
                         seed=sc.run_seeds(seed)['detector'])}


#: The array: plant seeds ``3 S`` .. ``3 S + 2``, detector seed ``S + 1000``, the chip
#: ``random_chip(S)``, the layout of ``S`` (:mod:`fiber_align.simulation.array_scenarios`).
ARRAY = Machine('array', ARRAY_NAMESPACE, AXES, OWN_NODES,
                lambda seed: tuple(sc.run_seeds(seed)['plant'] + i for i in range(len(AXES))),
                _seeded, RECORDED, STREAMS)


def build_array(namespace=ARRAY_NAMESPACE, composed=None, sync_mode='', controller='',
                params_file='', seed=0, record='', config_directory=None, overrides=None):
    """Describe the array for the launch arguments (:func:`~.rig.build_axes`, ARRAY)."""
    return build_axes(ARRAY, namespace, composed, sync_mode, controller, params_file,
                      seed, record, config_directory, overrides)
