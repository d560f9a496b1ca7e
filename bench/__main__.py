# SPDX-License-Identifier: Apache-2.0
"""Run every ``bench/bench_*.py`` (or those named on the command line) and print tables."""

import importlib
from pathlib import Path
import sys


def main(argv=None):
    """Run the benchmarks; return an exit code."""
    argv = sys.argv[1:] if argv is None else argv
    here = Path(__file__).resolve().parent
    names = argv or sorted(p.stem for p in here.glob('bench_*.py'))
    for name in names:
        mod = importlib.import_module('bench.' + name)
        print('\n## %s\n' % name, flush=True)
        mod.main()
    return 0


if __name__ == '__main__':
    sys.exit(main())
