# SPDX-License-Identifier: Apache-2.0
"""
An alignment's record from what the sequencer publishes: the graph side's pure core.

:class:`AlignmentLog` reads the sequencer's statuses (the JSON of ``alignment_state``) and
the optical power (W) and returns the catalogue's rows
(:func:`fiber_align.records.rows.alignment_row`) as alignments end: SEARCHING starts one,
PEAKING is its first light, TRACKING its peak (s from the start, on the sequencer's
clock or in periods where the machine counts them), RELEASING, IDLE or FAULT end it; its
part is the one set when it started. :class:`RunTally`: a run's end figures from
``/diagnostics``. The rules in full: docs/records.md ("The graph's side").
"""

import json
import math

from fiber_align.alignment.states import FAULT, IDLE, PEAKING, RELEASING, SEARCHING, \
    TRACKING
from fiber_align.records import rows

#: The states that end an open alignment.
ENDS = (RELEASING, IDLE, FAULT)


def _raise_peak(a, power_w):
    """Raise the open alignment ``a``'s peak power (W) to ``power_w`` (W, finite)."""
    a['peak_w'] = float(power_w) if a['peak_w'] is None else max(a['peak_w'], float(power_w))


class AlignmentLog:
    """
    The alignments of one run (see the module docstring).

    :param run_id: the run's id; :param reference_power_w: the power of a loss of 0 dB
        (W), or None (no loss figure); :param period_s: the control period (s), or None
        (times from ``sample_time_s`` only).
    """

    def __init__(self, run_id, reference_power_w=None, period_s=None):
        """Start with no alignment open and no part set."""
        self.run_id = run_id
        self.reference_power_w = reference_power_w
        self.period_s = period_s
        self.part_id = None
        self.seq = 0
        self.open = None
        self.last = {}          # the latest status (the samples of an alignment cut by the end)

    def set_part(self, part_id):
        """Set the part of the alignments that start from now on (text, or None)."""
        self.part_id = part_id or None

    def on_power(self, power_w):
        """Take one optical power reading (W) of the open alignment (None: none)."""
        a = self.open
        if a is None or power_w is None or not math.isfinite(power_w):
            return
        a['last_w'] = float(power_w)
        _raise_peak(a, power_w)

    def on_status(self, status, wall_s=None):
        """
        Take one status of the sequencer; return the rows of the alignments it ended.

        :param status: the published dict; :param wall_s: its receipt time (s since the
            epoch; None: now), the row's ``started_at``/``ended_at``.
        """
        state, t = status.get('state'), status.get('sample_time_s')
        self.last = status
        out = []
        a = self.open
        peak = status.get('peak_power_w')      # of the readings since the previous status
        if a is not None and peak is not None and math.isfinite(peak):
            _raise_peak(a, peak)
        if a is not None and state in ENDS:
            if state == FAULT:
                a.update(state=FAULT, fault=status.get('fault_reason') or None)
            out.append(self._row(a, status, wall_s))
            self.open = a = None
        if state in (SEARCHING, PEAKING) and a is None:
            if 'part_id' in status:
                self.set_part(status['part_id'])
            self.seq += 1
            # a switch on: its command acted before update ``sample`` (align_sample is
            # the last align's)
            k0 = status.get('sample' if state == PEAKING else 'align_sample')
            self.open = a = dict(seq=self.seq, part=self.part_id, t0=t,
                                 wall0=rows.stamp(wall_s), state=state, first_light=None,
                                 peak=None, fault=None, peak_w=None, last_w=None, sample0=k0)
            if state == PEAKING:
                a['first_light'] = 0.0
        elif a is not None and state:
            if state == PEAKING and a['first_light'] is None:
                a['first_light'] = self._since(a, status)
            if state == TRACKING and a['peak'] is None:
                a['peak'] = self._since(a, status)
            a['state'] = state
        return out

    def close(self, wall_s=None):
        """End the run: return the open alignment's row (its state as it was), if any."""
        a, self.open = self.open, None
        return [] if a is None else [self._row(a, self.last, wall_s)]

    def _since(self, a, status):
        """Return the time (s) from the alignment's start to the state of ``status``."""
        k = status.get('sample')
        if self.period_s and a['sample0'] is not None and k is not None:
            return (int(k) - 1 - int(a['sample0'])) * float(self.period_s)
        t0, t = a['t0'], status.get('sample_time_s')
        return None if t0 is None or t is None else float(t) - float(t0)

    def _row(self, a, status, wall_s):
        loss, last = None, status.get('power_w', a['last_w'])
        last = a['last_w'] if last is None else float(last)
        if self.reference_power_w and last is not None and last > 0.0:
            loss = -10.0 * math.log10(last / self.reference_power_w)
        samples = None
        if a['sample0'] is not None and status.get('sample') is not None:
            samples = int(status['sample']) - int(a['sample0'])
        return rows.alignment_row(
            self.run_id, a['seq'], a['part'], a['wall0'], rows.stamp(wall_s), a['state'],
            {}, fault_reason=a['fault'], time_to_first_light_s=a['first_light'],
            time_to_peak_s=a['peak'], peak_power_w=a['peak_w'], final_loss_db=loss,
            samples=samples)


class RunTally:
    """
    A run's end figures from the graph's ``/diagnostics`` (values as text, as published).

    A plant's status (it carries ``sim_time_s``) gives its updates ``sample`` and, in
    realtime, its ``missed_cycles``: the cycles it kept are ``sample - missed_cycles``,
    and the run's are the fewest any axis kept. A driver's status (``watchdog_count``, one
    per driver or per axis of an amplifier) gives its watchdog trips; the run's are the
    sum of each status's latest count.
    """

    def __init__(self):
        """Start with nothing seen."""
        self.kept, self.trips = {}, {}

    def on_status(self, name, values):
        """Take one status: its ``name`` and ``{key: text}`` values."""
        try:
            if 'sim_time_s' in values and 'sample' in values:
                self.kept[name] = int(values['sample']) - int(values.get('missed_cycles', 0))
            if 'watchdog_count' in values:
                self.trips[name] = int(values['watchdog_count'])
        except ValueError:
            pass            # a value that is no count: not a figure of the run

    def figures(self):
        """Return ``{'cycles_kept': int or None, 'watchdog_trips': int or None}``."""
        return dict(cycles_kept=min(self.kept.values()) if self.kept else None,
                    watchdog_trips=sum(self.trips.values()) if self.trips else None)


class RunRecord:
    """
    One graph run's rows: its ``runs`` row (at the start, again at the end), its alignments.

    :param run: ``machine``, ``sync_mode``, ``hardware``, ``bag_path`` (``''``: none),
        ``graph_parameters`` (JSON text, ``''``: none), ``reference_power_w`` (W; 0: no
        loss figure); :param period_s: the control period (s).
    """

    def __init__(self, run, period_s):
        """Start the run now: a new run id, no alignment, nothing tallied."""
        self.run = dict(run)
        self.run_id, self.started_at = rows.new_run_id(), rows.stamp()
        self.log = AlignmentLog(self.run_id, self.run['reference_power_w'] or None, period_s)
        self.tally, self.state = RunTally(), None
        #: the flight recorder's snapshot bags of the run (paths, as announced)
        self.snapshots = []

    def on_snapshot(self, path):
        """Take a snapshot bag's path (``snapshot_written``); return the run's row anew."""
        if path and path not in self.snapshots:
            self.snapshots.append(str(path))
        return self.start_row()

    def start_row(self, **end):
        """Return the run's row (``end``: its end columns; the snapshots so far)."""
        r = self.run
        try:
            params = json.loads(r['graph_parameters']) if r['graph_parameters'] else None
        except ValueError:
            params = None
        return rows.run_row(self.run_id, r['machine'] or None, r['sync_mode'], r['hardware'],
                            params, self.started_at, bag_path=r['bag_path'] or None,
                            snapshot_paths=list(self.snapshots) or None, **end)

    def on_status(self, text):
        """Take one ``alignment_state`` (JSON text); return the rows it ended."""
        try:
            status = json.loads(text)
        except ValueError:
            return []
        self.state = status.get('state', self.state)
        return self.log.on_status(status)

    def end_rows(self):
        """End the run: ``[('alignments', row) ..., ('runs', row)]``."""
        out = [('alignments', row) for row in self.log.close()]
        return out + [('runs', self.start_row(
            ended_at=rows.stamp(), end_reason='stopped; sequencer %s' % (
                self.state or 'not seen'), **self.tally.figures()))]
