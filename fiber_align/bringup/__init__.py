# SPDX-License-Identifier: Apache-2.0
"""
``bringup``: start the fiber_align graph, run a scenario, record, stop, summarise.

The pip-only way to start the graph that ``ros2 launch fiber_align
fiber_align.launch.py`` starts, for machines without the ROS 2 command line. By default
the control nodes (and the scenario's source) run in one ``control_graph`` process
(``--multi-process``: one process per node), the recorder (``--record DIR``) in its own.
The graph is the one description of :mod:`fiber_align.graph`, the launch file's: the
options are its launch arguments (:func:`~fiber_align.bringup.cli.graph`, through
:func:`fiber_align.graph.arguments.describe`),
``--params-file`` and ``-p NODE:NAME:=VALUE`` its user params, checked against the
shipped files (an unknown node or parameter, or a value of the wrong type, is refused).

Sequence (:class:`~fiber_align.bringup.harness.Harness`): refuse to start beside
another graph in the same namespace; start the recorder and the description's processes;
wait until every node is on the graph and ``lifecycle_manager`` has ``actuator_driver``
active; wait until every topic has its publishers and subscribers; start the plant
(``simulated_actuator/run``); run the scenario; hold the plant; stop every node (SIGINT,
SIGKILL at the deadline) and the recorder last; print the summary (metrics, realtime
figures, CPU and memory per process, sent and recorded counts).

Scenarios: ``step``, ``sine``, ``triangle``, ``staircase`` and
``hysteresis-experiment`` run the ``scenario_runner`` node (one setpoint, or open-loop
drive, per sample); ``align`` runs ``alignment_sequencer`` (align, then ``--cycles``
switch cycles); ``none`` runs until SIGINT (publish ``setpoint`` yourself).
``--rig`` runs the two-axis rig instead (:mod:`~fiber_align.bringup.rig`):
``align2d``, and in lockstep the comparison with the offline run.

Signals: SIGINT and SIGTERM stop the run cleanly however ``bringup`` was started (its
handlers are installed explicitly, also over an inherited SIG_IGN); a second signal
during the stop is noted and the stop goes on (bounded by ``stop_timeout_s``), so the bag
is still finalised. The node processes end with ``bringup`` even when it is killed,
and ``bringup`` stops as on SIGTERM when the process that started it is gone
(:func:`fiber_align.lifeline.watch_parent`). Exit codes: 0 a clean run, 1 a failure (a
node died, a timeout, a stall, another graph on the domain, an alignment FAULT,
``--strict`` goals missed), 2 bad input (options, params files, parameter values), 130
interrupted.

``--hardware`` runs the sensorless bench graph instead (``--emulate``: on the emulators;
:mod:`fiber_align.bringup.hardware`); ``--rig --hardware`` the two-axis rig on one
MDT693B. ``--station`` runs the coupled station as the rig (its sequence, its summary).
"""

import os
import signal
import sys

from fiber_align import lifeline
from fiber_align.bringup import hardware, interrupt
from fiber_align.bringup.cli import graph, parse_args
from fiber_align.bringup.rig import run_rig
from fiber_align.bringup.run import Bringup
from fiber_align.config import ConfigError
from fiber_align.graph.description import dds_environment


def main(args=None):
    """Bring the graph up, run, stop, summarise; return (and exit with) the exit code."""
    # explicit handlers: a shell script's background job inherits SIGINT ignored
    signal.signal(signal.SIGINT, interrupt.handler)
    signal.signal(signal.SIGTERM, interrupt.handler)
    lifeline.watch_parent(lifeline.PARENT_PID, signal.SIGTERM)
    os.environ.update(dds_environment())
    a = parse_args(args)
    try:
        if a.hardware:
            code = hardware.run(a)
        elif a.rig or a.station:
            code = run_rig(a, graph(a)[0])
        else:
            code = Bringup(a, *graph(a)).run()
    except (ConfigError, ValueError) as exc:
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
        code = 2
    except KeyboardInterrupt:
        interrupt.handled()
        code = 130
    if args is None:
        sys.exit(code)
    return code
