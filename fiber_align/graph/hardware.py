# SPDX-License-Identifier: Apache-2.0
"""
The hardware (sensorless) variant of the graph of :mod:`fiber_align.graph.description`.

The same description with the simulated plant replaced by the bench: ``actuator_driver``
with the ``mdt693b`` backend drives a Thorlabs MDT693B channel (real or emulated), the
``power_meter`` node reads a PM100 and publishes ``optical_power``, and there is no
``displacement``: the compensator's inverse PI feedforward alone positions the bimorph
(``controller: feedforward``), and ``alignment_sequencer`` aligns on optical power against
the commanded displacement (``reference``), stepping once per reading (``sensorless``).
No ``fuzzy_pid_controller`` (no measurement to feed back) and no ``simulated_actuator``.

Parameters: the graph's files (:func:`fiber_align.graph.description.build`), then
:data:`HARDWARE_FILES` (``config/hardware.yaml``: ``/**`` sensorless at 100 Hz, the device
settings; ``config/sequencer_hardware.yaml``), then the user's ``params_file``, then
``port`` and ``visa_resource``. Used by ``launch/fiber_align.launch.py`` (``hardware:=true``) and
``bringup --hardware``. Pure Python (no rclpy)::

    g = build_hardware(port='/dev/serial/by-id/usb-FTDI_...',
                       visa_resource='USB0::0x1313::0x8078::P0001234::INSTR')
"""

import dataclasses
import os

from fiber_align.config import config_dir
from fiber_align.graph import description as gr
from fiber_align.graph.params import (check_user, COMPENSATOR, DRIVER, effective, GraphError,
                                      LIFECYCLE_MANAGER, merge_params, RECORDER,
                                      SCENARIO_RUNNER, SEQUENCER)

POWER_METER = 'power_meter'
#: Params files of the bench, merged after the graph's own (names in ``config/``).
HARDWARE_FILES = ('hardware.yaml', 'sequencer_hardware.yaml')
#: Nodes of the sensorless control process, in start order (the setpoint source first).
SENSORLESS_NODES = (SEQUENCER, COMPENSATOR, DRIVER)


def build_hardware(port='', visa_resource='', namespace='', composed=None, params_file='',
                   model_file='', record='', config_directory=None, overrides=None):
    """
    Describe the sensorless hardware graph; return a :class:`~fiber_align.graph.description.Graph`.

    Empty strings mean "as the params files say".

    :param port: the MDT693B's serial device: ``actuator_driver.port``.
    :param visa_resource: the PM100's VISA resource: ``power_meter.resource``.
    :param namespace: as :func:`fiber_align.graph.description.build` (and ``composed``,
        ``model_file``, ``record``, ``config_directory``).
    :param params_file: a params file (or a list) merged after the hardware files.
    :param overrides: ``{node: {name: value}}`` applied last (``bringup -p``).
    :raises GraphError: a value is not allowed or a file is missing (one clear line).
    """
    base = gr.build(namespace=namespace, composed=composed, model_file=model_file,
                    record=record, config_directory=config_directory)
    d = config_dir() if config_directory is None else config_directory
    files = list(base.params_files) + [os.path.join(str(d), f) for f in HARDWARE_FILES]
    for f in files:
        if not os.path.isfile(f):
            raise GraphError('config file %s is missing' % f)
    users = gr.user_files(params_file)
    check_user(files, users, overrides)
    files += users
    over = dict(base.overrides)
    over.pop(SCENARIO_RUNNER, None)
    if port:
        over[DRIVER] = {'port': str(port)}
    if visa_resource:
        over[POWER_METER] = {'resource': str(visa_resource)}
    over[LIFECYCLE_MANAGER] = {'node_names': [DRIVER]}
    over = gr.add_overrides(over, overrides)
    merged = merge_params(files, over, base.namespace)
    wide = effective(merged, DRIVER, base.namespace)
    if wide.get('backend') != 'mdt693b' or not wide.get('sensorless'):
        raise GraphError('the hardware graph needs actuator_driver.backend mdt693b and '
                         'sensorless true (a params file changed them)')
    if base.composed:
        # the recorder hosted beside the loop, as in the simulated graph (description.py)
        hosted = SENSORLESS_NODES + ((RECORDER,) if base.record else ())
        procs = [gr.Process(gr.COMPOSED_EXECUTABLE, gr.COMPOSED_EXECUTABLE,
                            hosted, ('--nodes', ','.join(hosted)))]
    else:
        procs = [gr.Process(n, n, (n,), node_name=n) for n in SENSORLESS_NODES]
    procs.append(gr.Process(POWER_METER, POWER_METER, (POWER_METER,),
                            node_name=POWER_METER))
    procs += [p for p in base.processes if p.name in (LIFECYCLE_MANAGER, RECORDER)]
    return dataclasses.replace(
        base, sync_mode=wide['sync_mode'], controller=wide['controller'], scenario='align',
        processes=tuple(procs), params_files=tuple(files), overrides=over,
        managed_nodes=(DRIVER,))


def emulator_priority():
    """
    Return the ``SCHED_FIFO`` priority of the emulators: the power meter node's (its params).

    The emulators stand for devices, which answer on time whatever the host does; at the
    normal policy they would be the one process of the feedforward's chain that other
    load could hold up (docs/hardware.md).
    """
    return int(build_hardware().node_params(POWER_METER).get('realtime_priority', 0))
