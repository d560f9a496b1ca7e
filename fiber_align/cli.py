# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align``: the command-line front end of the pure core.

Each area registers its own sub-commands, so this file only lists where they live.
A sub-command module provides ``register(subparsers)`` which adds its parser and sets
``func`` (called with the parsed namespace, returning an exit code).
"""

import argparse
import importlib
import sys

from fiber_align.config import ConfigError

# (module, what it adds) -- imported lazily so `fiber-align design` never loads ROS.
COMMAND_MODULES = [
    'fiber_align.design.cli',        # design
    'fiber_align.hysteresis.cli',    # identify
    'fiber_align.control.cli',       # simulate, fuzzy-surface
    'fiber_align.analysis.cli',      # analyze
    'fiber_align.analysis.bag_repair',  # bag-repair
    'fiber_align.hardware.cli',      # emulate
]


class UsageError(Exception):
    """Bad command-line usage; exits 2 with the message."""


def build_parser():
    """Build the top-level parser with every sub-command that is installed."""
    parser = argparse.ArgumentParser(
        prog='fiber-align',
        description='Design, identify, simulate and analyse the piezo bimorph fiber aligner.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
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
        return int(args.func(args) or 0)
    except (UsageError, ConfigError, ValueError) as exc:
        print('fiber-align %s: error: %s' % (args.command, exc), file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == '__main__':
    # Run through the package module so ``python -m fiber_align.cli`` and the console
    # script share one UsageError class.
    from fiber_align.cli import main as _main
    sys.exit(_main())
