# SPDX-License-Identifier: Apache-2.0
"""
The flight recorder added to a described graph (pure Python: no rclpy).

:func:`with_snapshots` takes a graph of :mod:`fiber_align.graph` and returns it with
``bag_recorder``'s ``snapshots`` set to the folder (absolute): a graph that records
(``record``) keeps its full bag and takes snapshots beside it; the 1-D graphs (simulated
or hardware) without ``record`` get the recorder with ``record`` false (snapshots only;
docs/records.md), a process of its own. The multi-axis graphs (rig, station, array)
record their own topic lists: without ``record`` they are refused in one line. Used by
the launch file (``snapshots:=DIR``) and ``bringup --snapshots DIR``.
"""

import dataclasses
import os

from fiber_align.graph import description as gd
from fiber_align.graph.params import GraphError, RECORDER


def with_snapshots(graph, snapshots=''):
    """
    Return ``graph`` with the flight recorder writing into ``snapshots`` (``''``: as it is).

    :raises GraphError: ``snapshots`` names a file, or a multi-axis graph without a recorder.
    """
    if not snapshots:
        return graph
    folder = os.path.abspath(str(snapshots))
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise GraphError('snapshots %s is a file: give a folder' % folder)
    overrides = {k: dict(v) for k, v in graph.overrides.items()}
    overrides[RECORDER] = dict(overrides.get(RECORDER, {}), snapshots=folder)
    procs = graph.processes
    if RECORDER not in graph.nodes:
        if any(p.namespace is not None for p in procs):
            raise GraphError('snapshots: a multi-axis graph only with record:= (the '
                             'station, the array: the recorder records their topics; the '
                             'rig records none)')
        overrides[RECORDER]['record'] = False
        # a process of its own, also beside a composed graph: hosted in control_graph,
        # its snapshot writes (a 12 s window, 100,000 messages, in a Python thread) held
        # the control thread's GIL: the plant missed 166-242 periods of a 17 s run, and
        # the missed-cycles trigger asked for more (flight recorder test, 2026-12-06)
        procs = procs + (gd.Process(RECORDER, RECORDER, (RECORDER,), node_name=RECORDER),)
    return dataclasses.replace(graph, processes=procs, overrides=overrides)
