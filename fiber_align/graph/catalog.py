# SPDX-License-Identifier: Apache-2.0
"""
The run catalogue's node added to a described graph (pure Python: no rclpy).

:func:`with_catalog` takes any graph of :mod:`fiber_align.graph` (the 1-D graph, the rig,
the station, the hardware variants) and returns it with one more process, ``run_catalog``
(executable ``run_catalog``, in the graph's namespace, a process of its own: never inside
``control_graph``), reading ``config/records.yaml`` then what the graph knows of its run:
the catalogue's URL, the machine, real devices or not, the bag it records into, every
node's parameters (JSON) and the power of a loss of 0 dB. ``catalog`` ``''`` is the
file's default (``default``: SQLite ``$ROS_HOME/fiber_align/catalog.db``); ``none``
leaves the node out. A URL that cannot be written (a missing folder, a refused server, a
newer schema) is not refused here: the node says so in one line and the graph runs on
(docs/records.md). Used by the launch file (``catalog:=URL``) and ``bringup --catalog``.
"""

import dataclasses
import json
import os

from fiber_align.config import config_path, load_params
from fiber_align.graph import description as gd
from fiber_align.graph.params import ARRAY_SEQUENCER, GraphError, RUN_CATALOG, SEQUENCER_2D, \
    STATION_SEQUENCER
from fiber_align.records import backends
from fiber_align.records.schema import CatalogError

#: The catalogue's params file (in ``config/``).
RECORDS_FILE = 'records.yaml'


#: The sequencer node that names a multi-axis machine -> the catalogue's ``machine``.
MACHINE_OF = {SEQUENCER_2D: 'rig', STATION_SEQUENCER: 'station', ARRAY_SEQUENCER: 'array'}


def machine_of(graph):
    """Return the catalogue's ``machine`` of a graph: ``rig``, ``station``, ``array``, ``1d``."""
    return next((m for n, m in MACHINE_OF.items() if n in set(graph.nodes)), '1d')


def catalog_url(value):
    """
    Return the catalogue URL of the launch argument (``''``: ``config/records.yaml``'s).

    A relative SQLite path is made absolute (the node's working folder is not the
    caller's). :raises GraphError: a URL of no known form (one line).
    """
    url = str(value or '').strip() or str(load_params(RECORDS_FILE, RUN_CATALOG)['catalog'])
    try:
        parsed = backends.parse(url)
    except CatalogError as exc:
        raise GraphError('catalog: %s' % exc) from None
    if parsed is None:
        return backends.OFF
    if parsed[0] == 'sqlite' and url.lower() != backends.DEFAULT:
        return str(os.path.abspath(str(parsed[1])))
    return url


def with_catalog(graph, catalog='', hardware=False):
    """
    Return ``graph`` with the ``run_catalog`` process, or ``graph`` itself for ``none``.

    :param catalog: the launch argument (see the module docstring).
    :param hardware: the graph drives real devices (the run's ``hardware``).
    :raises GraphError: a URL of no known form.
    """
    url = catalog_url(catalog)
    if url == backends.OFF:
        return graph
    params = {k: v.get('ros__parameters', {}) for k, v in graph.params().items()}
    over = dict(catalog=url, machine=machine_of(graph), hardware=bool(hardware),
                bag_path=str(graph.record or ''),
                graph_parameters=json.dumps(params, sort_keys=True))
    overrides = {k: dict(v) for k, v in graph.overrides.items()}
    overrides[RUN_CATALOG] = dict(overrides.get(RUN_CATALOG, {}), **over)
    proc = gd.Process(RUN_CATALOG, RUN_CATALOG, (RUN_CATALOG,), node_name=RUN_CATALOG,
                      namespace=graph.namespace if graph.processes and
                      graph.processes[0].namespace is not None else None)
    return dataclasses.replace(
        graph, processes=graph.processes + (proc,),
        params_files=graph.params_files + (str(config_path(RECORDS_FILE)),),
        overrides=overrides)
