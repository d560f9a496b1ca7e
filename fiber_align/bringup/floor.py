# SPDX-License-Identifier: Apache-2.0
"""
The machine-floor probe's launcher: one :class:`Floor` beside every realtime run.

The probe: :mod:`fiber_align.control.floor_probe`; its use: docs/realtime.md.
"""

import json
import os
import subprocess
import sys

#: s: how long :meth:`Floor.stop` waits for the probe's figures
STOP_WAIT_S = 2.0


class Floor:
    """
    The probe process of one run, started by ``bringup`` beside the graph.

    :param rate_hz: the graph's rate (Hz). :param priority: the graph's
        ``realtime_priority`` (the probe takes one more; 0: both normal).
    :param directory: where the figures are written.
    """

    def __init__(self, rate_hz, priority, directory):
        """Start the probe (it ends with this process, or at :meth:`stop`)."""
        self.out = os.path.join(directory, 'floor.json')
        prio = min(99, int(priority) + 1) if int(priority) > 0 else 0
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'fiber_align.control.floor_probe', '--rate-hz',
             repr(float(rate_hz)), '--priority', str(prio), '--out', self.out],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True, start_new_session=True)
        self.figures = None

    def stop(self):
        """Stop the probe; return its figures (``{'error': ...}`` if it gave none)."""
        if self.figures is not None:
            return self.figures
        try:
            _, err = self.proc.communicate(timeout=STOP_WAIT_S)    # closes its stdin
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate(timeout=5.0)
        try:
            with open(self.out, encoding='utf-8') as f:
                self.figures = json.load(f)
        except (OSError, ValueError):
            self.figures = {'error': 'the machine-floor probe gave no figures (exit %s): %s'
                            % (self.proc.returncode, (err or '').strip()[-300:])}
        self.figures['pid'] = self.proc.pid
        return self.figures
