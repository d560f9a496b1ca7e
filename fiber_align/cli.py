# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align``: the command-line front end of the pure core.

Each area registers its own sub-commands, so this file only lists where they live.
A sub-command module provides ``register(subparsers)`` which adds its parser and sets
``func`` (called with the parsed namespace, returning an exit code) and ``paths`` (its
path arguments and their kinds, checked before ``func`` runs: :mod:`fiber_align.tools.paths`).
A bad path, a usage or config error and any OSError a command meets end in one line on
stderr and exit code 2.
"""

import argparse
import sys

from fiber_align.analysis import bag_repair, cli as analysis_cli
from fiber_align.config import ConfigError
from fiber_align.design import cli as design_cli
from fiber_align.hardware import cli as hardware_cli
from fiber_align.tools import identify_cli, runs_cli, simulate_cli
from fiber_align.tools.common import UsageError
from fiber_align.tools.paths import check_args, os_error_line

# The sub-command modules, in the order of the help text; none of them imports ROS.
COMMAND_MODULES = (
    design_cli,          # design
    identify_cli,        # identify
    simulate_cli,        # simulate, fuzzy-surface
    analysis_cli,        # analyze
    bag_repair,          # bag-repair
    hardware_cli,        # emulate
    runs_cli,            # runs (the run catalogue)
)


def build_parser():
    """Build the top-level parser with every sub-command that is installed."""
    parser = argparse.ArgumentParser(
        prog='fiber-align',
        description='Design, identify, simulate and analyse the piezo bimorph fiber aligner.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for mod in COMMAND_MODULES:
        mod.register(sub)
    return parser


def main(argv=None):
    """Run the CLI; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, 'func', None):
        parser.print_help()
        return 2
    try:
        check_args(args)
        return int(args.func(args) or 0)
    except (UsageError, ConfigError, ValueError) as exc:
        print('fiber-align %s: error: %s' % (args.command, exc), file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    except OSError as exc:
        print('fiber-align %s: error: %s' % (args.command, os_error_line(exc)),
              file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
