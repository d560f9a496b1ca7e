# SPDX-License-Identifier: Apache-2.0
"""
The machines the one sequencer node aligns, as data (pure Python: no rclpy).

A machine is its axes (the namespaces of its actuator graphs below the graph's), its pure
core (:class:`fiber_align.alignment.sequencer.Sequencer` for one axis,
:class:`~fiber_align.alignment.sequencer2d.Sequencer2D` for the rig,
:class:`~fiber_align.alignment.station.Station` for the coupled station,
:class:`~fiber_align.alignment.array.ArrayMachine` for the fiber array), the core's
calling convention and the status values it reports. The node ``alignment_sequencer``
reads its parameter ``machine`` and takes everything else from here. SI units.
"""

from dataclasses import dataclass
from typing import Callable, Tuple

from fiber_align.alignment import array as ar
from fiber_align.alignment import sequencer as sq, sequencer2d as s2d, station as st
from fiber_align.graph.registry import ARRAY_AXES, ARRAY_POWERS, STATION_AXES
from fiber_align.graph.hardware_rig import AMPLIFIER


@dataclass(frozen=True)
class Machine:
    """
    What one machine's sequencer differs by.

    :ivar module: the core's module (``CONFIG_FILE``, ``CONFIG_NODE``: its parameters).
    :ivar axes: the axes' namespaces (``''``: the node's own, the 1-D graph).
    :ivar build: ``(params, period_s, path_rate_m_per_s or None) -> core``.
    :ivar update: ``(core, t_s, positions_m, powers_w) -> setpoints_m``; a position or a
        power is ``None`` when no valid reading arrived; one power per :attr:`powers`.
    :ivar setpoints: ``core -> setpoints_m`` (the last ones, one per axis).
    :ivar values: keys of the core's ``status()`` also reported on ``/diagnostics``.
    :ivar counted: lockstep updates at ``t_i = i / rate_hz`` and the status carries
        ``sample`` and ``align_sample``; ``False``: at the displacement's stamp.
    :ivar amplifier: sensorless (the hardware graph): the one amplifier node whose
        transitions and per-axis statuses stand for every axis's driver (``''``: none).
    :ivar powers: the topics of the power readings (W) it takes, paired by index.
    """

    module: object
    axes: Tuple[str, ...]
    build: Callable
    update: Callable
    setpoints: Callable
    values: Tuple[str, ...] = ()
    counted: bool = True
    amplifier: str = ''
    powers: Tuple[str, ...] = ('optical_power',)

    def driver(self, axis):
        """Return the core's name of the driver of ``axis`` (relative to the graph's)."""
        return (axis + '/' if axis else '') + 'actuator_driver'


#: Every machine, by the value of the sequencer's ``machine`` parameter.
MACHINES = {
    '1d': Machine(sq, ('',), lambda p, period, rate: sq.Sequencer(p),
                  lambda c, t, x, p: (c.update(t, x[0], p[0]),), lambda c: (c.setpoint_m,),
                  ('aligned_position_m',), counted=False),
    'rig': Machine(s2d, ('x', 'y'), s2d.Sequencer2D,
                   lambda c, t, x, p: c.update(t, x[0], x[1], p[0]), lambda c: c.setpoint,
                   ('aligned_x_m', 'aligned_y_m'), amplifier=AMPLIFIER),
    'station': Machine(st, STATION_AXES, st.Station,
                       lambda c, t, x, p: c.update(t, None if None in x else list(x), p[0]),
                       lambda c: c.setpoint),
    'array': Machine(ar, ARRAY_AXES, ar.ArrayMachine,
                     lambda c, t, x, p: c.update(t, None if None in x else list(x), p),
                     lambda c: c.setpoint, amplifier=AMPLIFIER, powers=ARRAY_POWERS),
}
#: The params files of the machines' cores, where each sequencer node's section is.
CONFIG_FILES = tuple(dict.fromkeys(m.module.CONFIG_FILE for m in MACHINES.values()))
