# SPDX-License-Identifier: Apache-2.0
"""
``bringup``: start the fiber_align graph, run a scenario, record, stop, summarise.

The pip-only way to start the graph that ``ros2 launch fiber_align
fiber_align.launch.py`` starts, for machines without the ROS 2 command line: the options
are its launch arguments (:func:`fiber_align.graph.arguments.describe` of
:func:`~fiber_align.bringup.cli.arguments`), ``--params-file`` and ``-p
NODE:NAME:=VALUE`` its user params, checked against the shipped files. Every graph runs
on the one :class:`~fiber_align.bringup.harness.Harness`; what is run on it:

- the 1-D graph (default): its scenario, or ``align`` (:mod:`~fiber_align.bringup.run`);
- ``--rig``, ``--station``: ``align2d``, the station; in lockstep compared with the
  offline run (:mod:`~fiber_align.bringup.rig`);
- ``--hardware [--rig] [--emulate]``: the sensorless bench, on an MDT693B + PM100 or
  their emulators (:mod:`~fiber_align.bringup.hardware`).

Signals: SIGINT and SIGTERM stop the run cleanly however ``bringup`` was started (its
handlers are installed explicitly, also over an inherited SIG_IGN); a second signal
during the stop is noted and the stop goes on (bounded by ``stop_timeout_s``), so the bag
is still finalised. The node processes end with ``bringup`` even when it is killed,
and ``bringup`` stops as on SIGTERM when the process that started it is gone
(:func:`fiber_align.lifeline.watch_parent`). Exit codes: 0 a clean run, 1 a failure (a
node died, a timeout, a stall, another graph on the domain, an alignment FAULT,
``--strict`` goals missed), 2 bad input (options, params files, parameter values), 130
interrupted.
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
from fiber_align.graph.endpoints import NamesTaken
from fiber_align.nodes.ros.owners import refuse_taken


def main(args=None):
    """Bring the graph up, run, stop, summarise; return (and exit with) the exit code."""
    # explicit handlers: a shell script's background job inherits SIGINT ignored
    signal.signal(signal.SIGINT, interrupt.handler)
    signal.signal(signal.SIGTERM, interrupt.handler)
    lifeline.watch_parent(lifeline.PARENT_PID, signal.SIGTERM)
    os.environ.update(dds_environment())
    a = parse_args(args)
    try:
        refuse_taken(graph(a)[0])   # another graph of these names: one line, nothing started
        if a.hardware:
            code = hardware.run(a)
        elif a.rig or a.station or a.array:
            code = run_rig(a, graph(a)[0])
        else:
            code = Bringup(a, *graph(a)).run()
    except (ConfigError, ValueError) as exc:
        print('bringup: error: %s' % exc, file=sys.stderr, flush=True)
        code = 1 if isinstance(exc, NamesTaken) else 2
    except KeyboardInterrupt:
        interrupt.handled()
        code = 130
    if args is None:
        sys.exit(code)
    return code
