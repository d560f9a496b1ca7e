# SPDX-License-Identifier: Apache-2.0
"""
The catalogue's rows: a run's row and its alignments' rows, built from what a run reports.

Times are text (:func:`stamp`: ISO 8601 UTC, fixed width, microseconds); figures in SI
units and dB. :func:`alignment_rows` turns the result of a machine's scenario (the
dictionary ``fiber-align simulate --json`` prints) into rows: ``seq`` 1 is the alignment;
a scenario of switch cycles adds one row per cycle (``seq`` 2, 3, ...), its loss the
cycle's mean loss at the end of the on period.
"""

import datetime
import json
import uuid

from fiber_align import __version__
from fiber_align.jsonout import json_clean

#: The result keys that are columns of an alignment; the others go into ``figures``.
COLUMN_KEYS = ('fault_reason', 'time_to_first_light_s', 'time_to_peak_s', 'peak_power_w',
               'final_loss_db', 'samples')
#: Keys of a result that are not the alignment's figures (the run's, or bulky).
NOT_FIGURES = ('trace', 'baseline', 'scenario', 'seed', 'loop', 'control_rate_hz',
               'end_state', 'state', 'end_fault_reason') + COLUMN_KEYS


def stamp(t=None):
    """Return the catalogue's text of a time (``t``: seconds since the epoch; None: now)."""
    if t is None:
        d = datetime.datetime.now(datetime.timezone.utc)
    else:
        d = datetime.datetime.fromtimestamp(float(t), datetime.timezone.utc)
    return d.strftime('%Y-%m-%dT%H:%M:%S.%fZ')


def parse_stamp(text):
    """Return the seconds since the epoch of a catalogue time, or of a date ``YYYY-MM-DD``."""
    text = str(text).strip()
    for fmt in ('%Y-%m-%dT%H:%M:%S.%fZ', '%Y-%m-%dT%H:%M:%SZ', '%Y-%m-%dT%H:%M:%S',
                '%Y-%m-%d %H:%M:%S', '%Y-%m-%d'):
        try:
            d = datetime.datetime.strptime(text, fmt)
        except ValueError:
            continue
        return d.replace(tzinfo=datetime.timezone.utc).timestamp()
    raise ValueError('not a time: %r (use YYYY-MM-DD or YYYY-MM-DDTHH:MM:SSZ, UTC)' % text)


def new_run_id():
    """Return a new run id (a UUID, text)."""
    return str(uuid.uuid4())


def run_row(run_id, machine, sync_mode, hardware, parameters, started_at, ended_at=None,
            bag_path=None, cycles_kept=None, watchdog_trips=None, end_reason=None,
            snapshot_paths=None):
    """
    Return one row of ``runs`` (``parameters``: a mapping, stored as JSON).

    :param snapshot_paths: the flight recorder's bags of the run (a list of paths, stored
        as JSON; None: none).
    """
    return dict(run_id=run_id, started_at=started_at, ended_at=ended_at, machine=machine,
                sync_mode=sync_mode, hardware=bool(hardware), package_version=__version__,
                parameters=_json(parameters), bag_path=bag_path, cycles_kept=cycles_kept,
                watchdog_trips=watchdog_trips, end_reason=end_reason,
                snapshot_paths=_json(snapshot_paths))


def _json(value):
    return None if value is None else json.dumps(json_clean(value), sort_keys=True)


def alignment_row(run_id, seq, part_id, started_at, ended_at, final_state, figures=None,
                  **columns):
    """Return one row of ``alignments``; ``columns``: those of :data:`COLUMN_KEYS`."""
    unknown = set(columns) - set(COLUMN_KEYS)
    if unknown:
        raise ValueError('not alignment columns: %s' % ', '.join(sorted(unknown)))
    row = dict(run_id=run_id, seq=int(seq), part_id=part_id, started_at=started_at,
               ended_at=ended_at, final_state=final_state, figures=_json(figures or {}))
    row.update({k: columns.get(k) for k in COLUMN_KEYS})
    row['fault_reason'] = row['fault_reason'] or None
    return row


def alignment_rows(result, run_id, part_id, started_at, ended_at):
    """
    Return the alignment rows of a machine scenario's ``result`` (see the module docstring).

    :param result: the scenario's dictionary (SI units, dB), as ``simulate --json`` prints.
    """
    state = result.get('state') or result.get('end_state')
    figures = {k: v for k, v in result.items() if k not in NOT_FIGURES}
    rows = [alignment_row(run_id, 1, part_id, started_at, ended_at, state, figures,
                          **{k: result.get(k) for k in COLUMN_KEYS})]
    losses = result.get('cycle_loss_db') or []
    faults = result.get('switch_faults') or []
    for i, loss in enumerate(losses):
        fault = next((f for f in faults if f.startswith('cycle %d:' % i)), None)
        rows.append(alignment_row(
            run_id, i + 2, part_id, started_at, ended_at, 'FAULT' if fault else 'TRACKING',
            {'kind': 'switch cycle', 'cycle': i + 1}, final_loss_db=loss, fault_reason=fault))
    return rows
