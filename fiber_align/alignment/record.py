# SPDX-License-Identifier: Apache-2.0
"""
An alignment's record from what the sequencer publishes: the graph side's pure core.

:class:`AlignmentLog` reads the sequencer's statuses (the JSON of ``alignment_state``:
``state``, ``fault_reason``, ``sample_time_s`` s, and ``sample``/``align_sample`` where
the machine counts them) and the optical power (W), and returns the catalogue's rows
(:func:`fiber_align.records.rows.alignment_row`) as alignments end. An alignment starts
when the sequencer enters SEARCHING, reaches first light when it enters PEAKING and its
peak when it enters TRACKING (times from the start, s, on the sequencer's clock), and
ends at RELEASING, IDLE or FAULT; its final state is the one it was in
(TRACKING, HELD, FAULT, ...); a SEARCHING again within it (false light, a re-search) does
not end it. The part is the one set when the alignment started: a
part set during an alignment applies to the next one, so a row never mixes two parts.
The final loss is ``-10 log10(P / reference_power_w)`` (dB) of the last power before the
end, when a reference power is given. Used by the catalogue's node (docs/records.md).
"""

import math

from fiber_align.alignment.states import FAULT, IDLE, PEAKING, RELEASING, SEARCHING, \
    TRACKING
from fiber_align.records import rows

#: The states that end an open alignment.
ENDS = (RELEASING, IDLE, FAULT)


class AlignmentLog:
    """
    The alignments of one run (see the module docstring).

    :param run_id: the run's id; :param reference_power_w: the power of a loss of 0 dB
        (W), or None (no loss figure).
    """

    def __init__(self, run_id, reference_power_w=None):
        """Start with no alignment open and no part set."""
        self.run_id = run_id
        self.reference_power_w = reference_power_w
        self.part_id = None
        self.seq = 0
        self.open = None

    def set_part(self, part_id):
        """Set the part of the alignments that start from now on (text, or None)."""
        self.part_id = part_id or None

    def on_power(self, power_w):
        """Take one optical power reading (W) of the open alignment."""
        a = self.open
        if a is None or power_w is None or not math.isfinite(power_w):
            return
        a['last_w'] = float(power_w)
        a['peak_w'] = max(a['peak_w'], float(power_w)) if a['peak_w'] is not None \
            else float(power_w)

    def on_status(self, status, wall_s=None):
        """
        Take one status of the sequencer; return the rows of the alignments it ended.

        :param status: the published dict; :param wall_s: its receipt time (s since the
            epoch; None: now), the row's ``started_at``/``ended_at``.
        """
        state, t = status.get('state'), status.get('sample_time_s')
        out = []
        a = self.open
        if a is not None and state in ENDS:
            if state == FAULT:
                a.update(state=FAULT, fault=status.get('fault_reason') or None)
            out.append(self._row(a, status, wall_s))
            self.open = a = None
        if state == SEARCHING and a is None:
            self.seq += 1
            self.open = dict(seq=self.seq, part=self.part_id, t0=t, wall0=rows.stamp(wall_s),
                             state=SEARCHING, first_light=None, peak=None, fault=None,
                             peak_w=None, last_w=None, sample0=status.get('align_sample'))
        elif a is not None and state:
            if state == PEAKING and a['first_light'] is None:
                a['first_light'] = _since(a['t0'], t)
            if state == TRACKING and a['peak'] is None:
                a['peak'] = _since(a['t0'], t)
            a['state'] = state
        return out

    def close(self, wall_s=None):
        """End the run: return the open alignment's row (its state as it was), if any."""
        a, self.open = self.open, None
        return [] if a is None else [self._row(a, {}, wall_s)]

    def _row(self, a, status, wall_s):
        loss = None
        if self.reference_power_w and a['last_w'] is not None and a['last_w'] > 0.0:
            loss = -10.0 * math.log10(a['last_w'] / self.reference_power_w)
        samples = None
        if a['sample0'] is not None and status.get('sample') is not None:
            samples = int(status['sample']) - int(a['sample0'])
        return rows.alignment_row(
            self.run_id, a['seq'], a['part'], a['wall0'], rows.stamp(wall_s), a['state'],
            {}, fault_reason=a['fault'], time_to_first_light_s=a['first_light'],
            time_to_peak_s=a['peak'], peak_power_w=a['peak_w'], final_loss_db=loss,
            samples=samples)


def _since(t0, t):
    return None if t0 is None or t is None else float(t) - float(t0)
