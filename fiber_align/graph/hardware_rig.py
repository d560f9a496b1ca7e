# SPDX-License-Identifier: Apache-2.0
"""
The two-axis rig on hardware: one MDT693B drives x and y, a PM100 reads the power (pure).

The rig of :mod:`fiber_align.graph.rig` with the simulated plants and optics replaced by
the bench, sensorless as the 1-D hardware graph (:mod:`fiber_align.graph.hardware`).
Under the rig namespace (``rig`` unless told):

- ``/rig/x/hysteresis_compensator``, ``/rig/y/hysteresis_compensator``: each axis's
  inverse PI feedforward (``controller: feedforward``) of its own model file, from
  ``x/setpoint`` to ``x/feedforward_voltage`` and ``x/reference`` (y alike);
- ``/rig/mdt693b_driver`` (lifecycle): the amplifier's one owner, both axes' limits,
  slew and watchdogs, both channels over one serial link: the executable
  ``actuator_driver`` with ``axes: [x, y]`` and backend ``mdt693b``, under this name;
- ``/rig/power_meter``: ``optical_power`` from the PM100;
- ``/rig/alignment_sequencer_2d``: the 2-D sequencer on that power against the
  commanded positions (``x/reference``, ``y/reference``), one update per reading;
- ``/rig/lifecycle_manager``: configures and activates ``mdt693b_driver``.

Composed (default): a ``control_graph`` process per axis (its compensator; a composed
process has one namespace), one for the sequencer and the driver, and the meter and
the manager alone. Params: the rig's files, then :data:`HARDWARE_RIG_FILES`
(``hardware.yaml``'s ``/**``: sensorless, 100 Hz; ``hardware_rig.yaml``: the wiring and
each axis's limits and model, the file a user edits; ``sequencer2d_hardware.yaml``), the
user's ``params_file``, then ``port`` and ``visa_resource``. Used by the launch file
(``rig:=true hardware:=true``) and ``bringup --rig --hardware``.

The machine is data (:class:`HardwareMachine`): :data:`HARDWARE_RIG` above, and
:data:`HARDWARE_ARRAY`, the fiber array (:mod:`fiber_align.graph.array`) on one MDT693B
(its channels x, y, z carry ``x``, ``y_left``, ``y_right``; ``hardware_array.yaml``) with
the array sequencer and two PM100s: ``power_meter`` (channel 1, ``optical_power``) and
``power_meter_n`` (channel N, the same executable, ``optical_power_n``); ``visa_resource``
``A,B`` names them in that order. Launch ``array:=true hardware:=true``, ``bringup
--array --hardware``.
"""

import copy
from dataclasses import dataclass
import os
from typing import Callable, Tuple

from fiber_align.config import config_dir
from fiber_align.graph import description as g
from fiber_align.graph.hardware import POWER_METER
from fiber_align.graph.params import (AMPLIFIER, ARRAY_SEQUENCER, check_user, COMPENSATOR,
                                      effective, GraphError, LIFECYCLE_MANAGER, LIVE_VIEW,
                                      merge, merge_params, RUN_CATALOG, wildcard_first)
from fiber_align.graph.registry import ARRAY_AXES, ARRAY_POWERS
from fiber_align.graph.rig import (_axis_ns, AXES, RIG_FILES, RIG_NAMESPACE, RigGraph,
                                   SEQUENCER_2D)
from fiber_align.simulation.array_scenarios import random_chip
from fiber_align.simulation.seeds2d import random_target

#: The amplifier's ROS arguments: the one driver executable under the rig's node name
#: (a node-specific rule: in a composed process it renames the driver alone).
AMPLIFIER_ARGS = ('--ros-args', '-r', '%s:__node:=%s' % (
    g.NODES[AMPLIFIER].executable, AMPLIFIER), '--')
#: Params files of the hardware rig, merged after the rig's own (names in ``config/``).
HARDWARE_RIG_FILES = ('hardware.yaml', 'hardware_rig.yaml', 'sequencer2d_hardware.yaml')
CHANNELS = ('x', 'y', 'z')
#: The second meter of the array: the ``power_meter`` executable, channel N's topic.
POWER_METER_N = 'power_meter_n'


@dataclass(frozen=True)
class HardwareMachine:
    """
    A graph of several axes on one MDT693B, sensorless, as data.

    :ivar name: its process label (``rig``, ``array``) and default namespace.
    :ivar axes: the axes (amplifier ``axes``; each a compensator's namespace).
    :ivar sequencer: the sequencer node (``alignment_sequencer`` with its ``machine``).
    :ivar files: params files after the area files (names in ``config/``).
    :ivar meters: ``(node, power topic)`` of each PM100, in ``visa_resource``'s order.
    :ivar scenario: the offline scenario the graph's alignment is.
    :ivar truth: the emulator's truth of a run seed (the simulated machine's: the rig's
        target, the array's chip), ``fiber-align emulate``'s option of ``--emulate``.
    """

    name: str
    axes: Tuple[str, ...]
    sequencer: str
    files: Tuple[str, ...]
    meters: Tuple[Tuple[str, str], ...]
    scenario: str
    truth: Callable

    @property
    def root_nodes(self):
        """Return ``{node: executable}`` of the sequencer and the amplifier."""
        return {n: g.NODES[n].executable for n in (self.sequencer, AMPLIFIER)}


HARDWARE_RIG = HardwareMachine('rig', AXES, SEQUENCER_2D, RIG_FILES + HARDWARE_RIG_FILES,
                               ((POWER_METER, 'optical_power'),), 'align2d', random_target)
HARDWARE_ARRAY = HardwareMachine('array', ARRAY_AXES, ARRAY_SEQUENCER,
                                 tuple(g.NODES[ARRAY_SEQUENCER].configs) + (
                                     'hardware.yaml', 'hardware_array.yaml'),
                                 tuple(zip((POWER_METER, POWER_METER_N), ARRAY_POWERS)),
                                 'array', random_chip)
#: Nodes at the rig namespace (not per axis): name -> executable.
ROOT_NODES = HARDWARE_RIG.root_nodes


@dataclass(frozen=True)
class HardwareRigGraph(RigGraph):
    """The hardware rig (a :class:`~fiber_align.graph.rig.RigGraph`; node names relative)."""

    def params(self):
        """Return the merged params mapping, node sections keyed ``/<ns>[/<axis>]/<node>``."""
        base = merge_params(self.params_files, self.overrides)
        root = '/' + self.namespace if self.namespace else ''
        out = {'/**': base.get('/**', {'ros__parameters': {}})}
        for a in self.axes:
            n = COMPENSATOR
            sec = merge(base.get(n, {}), base.get('%s/%s' % (a, n), {}))
            if sec:
                out['%s/%s/%s' % (root, a, n)] = sec
        # the live view (``live:=true``) sits at the root too
        for n in tuple(self.own_nodes) + (LIFECYCLE_MANAGER, LIVE_VIEW, RUN_CATALOG):
            if n in base:
                out['%s/%s' % (root, n)] = base[n]
        return wildcard_first({k: copy.deepcopy(v) for k, v in out.items()})


def hardware_rig_processes(ns, composed, m=HARDWARE_RIG):
    """Return the processes of ``m`` (each with its namespace), the manager last."""
    root = m.root_nodes
    if composed:
        procs = [g.Process(a, g.COMPOSED_EXECUTABLE, (COMPENSATOR,), ('--nodes', COMPENSATOR),
                           namespace=_axis_ns(ns, a)) for a in m.axes]
        procs.append(g.Process(m.name, g.COMPOSED_EXECUTABLE, tuple(root),
                               ('--nodes', ','.join(root)) + AMPLIFIER_ARGS,
                               namespace=ns))
    else:
        procs = [g.Process('%s/%s' % (a, COMPENSATOR), COMPENSATOR, (COMPENSATOR,),
                           node_name=COMPENSATOR, namespace=_axis_ns(ns, a)) for a in m.axes]
        procs += [g.Process(n, exe, (n,), AMPLIFIER_ARGS if n == AMPLIFIER else (),
                            node_name=n, namespace=ns) for n, exe in root.items()]
    for n, topic in m.meters:   # the one executable; a second meter renamed and remapped
        procs.append(g.Process(n, POWER_METER, (n,), () if topic == 'optical_power' else (
            '--ros-args', '-r', 'optical_power:=' + topic, '--'), node_name=n, namespace=ns))
    procs.append(g.Process(LIFECYCLE_MANAGER, LIFECYCLE_MANAGER, (LIFECYCLE_MANAGER,),
                           node_name=LIFECYCLE_MANAGER, namespace=ns))
    return tuple(procs)


def check_wiring(p, want=AXES):
    """
    Return None or why the amplifier's axis parameters cannot drive the rig (one line).

    :param p: the effective parameters of ``mdt693b_driver`` (nested ``x``, ``y``).
    :param want: the machine's axes.
    """
    axes = list(p.get('axes') or [])
    if sorted(axes) != sorted(want):
        return 'mdt693b_driver.axes must be [%s], got %r' % (', '.join(want), axes)
    seen = {}
    for a in axes:
        sec = p.get(a) or {}
        ch = sec.get('channel')
        if ch not in CHANNELS:
            return 'mdt693b_driver.%s.channel %r is not one of x, y, z' % (a, ch)
        if ch in seen:
            return ('channel %s is named twice (mdt693b_driver.%s.channel and %s.channel)'
                    % (ch, seen[ch], a))
        seen[ch] = a
    return None


def build_hardware_rig(port='', visa_resource='', namespace=RIG_NAMESPACE, composed=None,
                       params_file='', config_directory=None, overrides=None,
                       machine=HARDWARE_RIG):
    """
    Describe the hardware rig (or another ``machine``); return a :class:`HardwareRigGraph`.

    :param port: the MDT693B's serial device: ``mdt693b_driver.port`` (``''``: the files').
    :param visa_resource: the PM100's VISA resource: ``power_meter.resource`` (several
        meters: ``A,B``, one per meter of ``machine.meters``, in order).
    :param namespace: the rig namespace (``rig``).
    :param composed: layout (bool or ``'true'``/``'false'``; ``None``/``''``: default).
    :param params_file: a params file (or a list) merged after the hardware files.
    :param overrides: ``{node: {name: value}}`` applied last (``bringup -p``).
    :raises GraphError: a value is not allowed, a channel is named twice, a file is
        missing (one clear line).
    """
    m = machine
    ns = g.check_namespace(namespace or m.name)
    composed = g.DEFAULT_COMPOSED if composed in (None, '') else g.parse_bool('composed',
                                                                              composed)
    d = config_dir() if config_directory is None else config_directory
    files = list(g.area_files(d)) + [os.path.join(str(d), f)
                                     for f in dict.fromkeys(m.files)]
    for f in files:
        if not os.path.isfile(f):
            raise GraphError('config file %s is missing' % f)
    users = g.user_files(params_file)
    check_user(files, users, overrides)
    files += users
    over = {'/**': {}}
    if port:
        over[AMPLIFIER] = {'port': str(port)}
    if visa_resource:
        res = [str(visa_resource)] if len(m.meters) == 1 else str(visa_resource).split(',')
        if len(res) != len(m.meters):
            raise GraphError('visa_resource %r: the %s needs %d VISA resources, A,B '
                             '(%s)' % (visa_resource, m.name, len(m.meters),
                                       ', '.join(t for _, t in m.meters)))
        for (n, _), r in zip(m.meters, res):
            over[n] = {'resource': r.strip()}
    over[LIFECYCLE_MANAGER] = {'node_names': [AMPLIFIER]}
    over = g.add_overrides(over, overrides)
    merged = merge_params(files, over)
    amp = effective(merged, AMPLIFIER)
    why = check_wiring(amp, m.axes)
    if why:
        raise GraphError(why)
    if not amp.get('sensorless') or amp.get('controller') != 'feedforward':
        raise GraphError('the hardware rig needs sensorless true and controller '
                         'feedforward (a params file changed them)')
    return HardwareRigGraph(namespace=ns, composed=composed, sync_mode=amp['sync_mode'],
                            controller=amp['controller'], scenario=m.scenario, record='',
                            processes=hardware_rig_processes(ns, composed, m),
                            params_files=tuple(files), overrides=over,
                            remappings=g.REMAPPINGS, managed_nodes=(AMPLIFIER,), seed=0,
                            axes=m.axes, own_nodes=tuple(m.root_nodes) + tuple(
                                n for n, _ in m.meters))


def build_hardware_array(port='', visa_resource='', namespace='', composed=None,
                         params_file='', config_directory=None, overrides=None):
    """Describe the fiber array on hardware (:func:`build_hardware_rig` of the array)."""
    return build_hardware_rig(port, visa_resource, namespace, composed, params_file,
                              config_directory, overrides, HARDWARE_ARRAY)
