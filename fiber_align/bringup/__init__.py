# SPDX-License-Identifier: Apache-2.0
"""
``bringup``: start the fiber_align graph, run a scenario, record, stop, summarise.

The pip-only way to start the graph of ``ros2 launch fiber_align fiber_align.launch.py``
(its launch arguments, ``--params-file``, ``-p NODE:NAME:=VALUE``) on the one
:class:`~fiber_align.bringup.harness.Harness`: the 1-D graph (:mod:`.run`), ``--rig``,
``--station``, ``--array`` (:mod:`.rig`), ``--hardware`` (:mod:`.hardware`).

SIGINT and SIGTERM stop it cleanly however it was started (a second one is only noted:
the bag is still finalised); its nodes end with it, also when it is killed. Exit codes: 0
a clean run, 1 a failure, 2 bad input, 130 interrupted (docs/ros_interface.md).
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
