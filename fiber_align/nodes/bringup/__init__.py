# SPDX-License-Identifier: Apache-2.0
"""
``bringup``: start the fiber_align graph, run a scenario, record, stop, summarise.

The pip-only way to start the graph that ``ros2 launch fiber_align
fiber_align.launch.py`` starts, for machines without the ROS 2 command line. By default
the control nodes (and the scenario's source) run in one ``control_graph`` process
(``--multi-process``: one process per node), the recorder (``--record DIR``) in its own.
Every node gets one composed params file: the per-area files, ``config/fiber_align.yaml``,
any ``--params-file`` and the ``-p NODE:NAME:=VALUE`` overrides, checked against the
shipped files (an unknown node or parameter, or a value of the wrong type, is refused).

Sequence: refuse to start beside another graph in the same namespace; start the
recorder and the nodes; wait until every node is on the graph; configure and activate
``actuator_driver`` (lifecycle ``ChangeState``); wait until every topic has its
publishers and subscribers; start the plant (``simulated_actuator/run``); run the
scenario; hold the plant; stop every node (SIGINT, SIGKILL at the deadline) and the
recorder last; print the summary (metrics, realtime figures, CPU and memory per process,
sent and recorded counts).

Scenarios: ``step``, ``sine``, ``triangle``, ``staircase`` and
``hysteresis-experiment`` run the ``scenario_runner`` node (one setpoint, or open-loop
drive, per sample); ``align`` runs ``alignment_sequencer`` (align, then ``--cycles``
switch cycles); ``none`` runs until SIGINT (publish ``setpoint`` yourself).
``--rig`` runs the two-axis rig instead (:mod:`~fiber_align.nodes.bringup.rig`):
``align2d``, and in lockstep the comparison with the offline run.

Signals: SIGINT and SIGTERM stop the run cleanly however ``bringup`` was started (its
handlers are installed explicitly, also over an inherited SIG_IGN); a second signal
during the stop is noted and the stop goes on (bounded by ``stop_timeout_s``), so the bag
is still finalised. The node processes end with ``bringup`` even when it is killed
(``PR_SET_PDEATHSIG``). Exit codes: 0 a clean run, 1 a failure (a node died, a timeout,
a stall, another graph on the domain, an alignment FAULT, ``--strict`` goals missed), 2
bad input (options, params files, parameter values), 130 interrupted.

``--hardware`` runs the sensorless bench graph instead (``--emulate``: on the emulators;
:mod:`fiber_align.nodes.bringup.hardware`).
"""

import os
import signal
import sys

from fiber_align.config import ConfigError
from fiber_align.nodes.bringup import hardware, interrupt
from fiber_align.nodes.bringup.cli import parse_args
from fiber_align.nodes.bringup.observer import BringupError, Runner, StartStall
from fiber_align.nodes.bringup.rig import rig_graph, run_rig
from fiber_align.nodes.bringup.run import (Bringup, dds_environment, expected_endpoints,
                                           graph_nodes)
from fiber_align.nodes.bringup.summary import scenario_skip_s

__all__ = ['Bringup', 'BringupError', 'Runner', 'StartStall', 'expected_endpoints',
           'graph_nodes', 'main', 'scenario_skip_s']


class _Rig:
    """``bringup --rig``: the two-axis rig (:mod:`~fiber_align.nodes.bringup.rig`)."""

    def __init__(self, args):
        """Describe the rig (a bad option raises ``GraphError``: exit code 2)."""
        self.args = args
        self.graph = rig_graph(args)

    def run(self):
        """Run align2d on the rig; return the exit code."""
        return run_rig(self.args, self.graph)


def main(args=None):
    """Bring the graph up, run, stop, summarise; return (and exit with) the exit code."""
    # explicit handlers: a shell script's background job inherits SIGINT ignored
    signal.signal(signal.SIGINT, interrupt.handler)
    signal.signal(signal.SIGTERM, interrupt.handler)
    os.environ.update(dds_environment())
    a = parse_args(args)
    if a.hardware:
        code = hardware.run(a)
        if args is None:
            sys.exit(code)
        return code
    try:
        b = _Rig(a) if a.rig else Bringup(a)
    except (ConfigError, ValueError) as exc:
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
        code = 2
    except KeyboardInterrupt:
        interrupt.handled()
        code = 130
    else:
        code = b.run()
    if args is None:
        sys.exit(code)
    return code
