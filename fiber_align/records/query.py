# SPDX-License-Identifier: Apache-2.0
"""
The reading tools' selections: runs and alignments by part, machine, date range, state.

One SQL text per selection for both dialects (:meth:`~.backends.Backend.sql`); rows come
back as dictionaries with the same Python types on SQLite and PostgreSQL (``hardware`` a
bool, JSON columns parsed, times the catalogue's text).
"""

from dataclasses import dataclass
import json

import numpy as np

from fiber_align.records import rows as rowlib, schema
from fiber_align.records.schema import CatalogError

#: One alignment with its run's machine, sync mode and hardware flag.
ALIGNMENTS = ('SELECT r.machine, r.sync_mode, r.hardware, %s FROM alignments a '
              'JOIN runs r ON a.run_id = r.run_id'
              % ', '.join('a.' + c for c in schema.names('alignments')))
ORDER = ' ORDER BY a.started_at, a.run_id, a.seq'
#: The columns of an exported alignment, in order.
EXPORT_COLUMNS = ('machine', 'sync_mode', 'hardware') + schema.names('alignments')


@dataclass
class Filters:
    """
    What a selection keeps; None keeps everything.

    :param part: ``part_id``; :param machine: ``runs.machine``; :param state: an
        alignment's ``final_state``; :param since: :param until: the alignment's (or, for
        runs, the run's) start: ``YYYY-MM-DD`` (a whole day for ``until``) or a UTC time.
    """

    part: str = None
    machine: str = None
    since: str = None
    until: str = None
    state: str = None


def _bounds(f):
    """Return the catalogue texts of ``[since, until)``."""
    lo = hi = None
    if f.since:
        lo = rowlib.stamp(rowlib.parse_stamp(f.since))
    if f.until:
        t = rowlib.parse_stamp(f.until)
        if len(str(f.until).strip()) == 10:        # a date: until the end of that day
            t += 86400.0
        hi = rowlib.stamp(t)
    return lo, hi


def _where(f, time_col):
    """Return ``(' WHERE ...', args)`` of the alignment filters (``a.``, ``r.`` aliases)."""
    terms, args = [], []
    for col, v in (('a.part_id', f.part), ('r.machine', f.machine), ('a.final_state', f.state)):
        if v is not None:
            terms.append('%s = ?' % col)
            args.append(v)
    lo, hi = _bounds(f)
    if lo:
        terms.append('%s >= ?' % time_col)
        args.append(lo)
    if hi:
        terms.append('%s < ?' % time_col)
        args.append(hi)
    return (' WHERE ' + ' AND '.join(terms) if terms else ''), args


def _clean(d):
    """Return a row dictionary with one type per column on both dialects."""
    for k in ('hardware',):
        if k in d and d[k] is not None:
            d[k] = bool(d[k])
    for k in ('parameters', 'figures', 'snapshot_paths'):
        if isinstance(d.get(k), str):
            d[k] = json.loads(d[k])
    return d


def alignments(db, f=None):
    """Return the alignments the filters keep (dicts, oldest first)."""
    where, args = _where(f or Filters(), 'a.started_at')
    rows, cols = db.query(ALIGNMENTS + where + ORDER, args)
    return [_clean(dict(zip(cols, r))) for r in rows]


def runs(db, f=None):
    """
    Return the kept runs, oldest first, as dicts with their alignment counts.

    Each run has ``alignments`` (its count) and ``tracking`` (those that ended TRACKING).

    A run is kept when its machine and start match and, if a part or a state is asked,
    one of its alignments has it.
    """
    f = f or Filters()
    terms, args = [], []
    if f.machine is not None:
        terms.append('r.machine = ?')
        args.append(f.machine)
    lo, hi = _bounds(f)
    if lo:
        terms.append('r.started_at >= ?')
        args.append(lo)
    if hi:
        terms.append('r.started_at < ?')
        args.append(hi)
    for col, v in (('part_id', f.part), ('final_state', f.state)):
        if v is not None:
            terms.append('EXISTS (SELECT 1 FROM alignments b WHERE b.run_id = r.run_id AND '
                         'b.%s = ?)' % col)
            args.append(v)
    sql = ('SELECT %s, (SELECT COUNT(*) FROM alignments a WHERE a.run_id = r.run_id) AS '
           "alignments, (SELECT COUNT(*) FROM alignments a WHERE a.run_id = r.run_id AND "
           "a.final_state = 'TRACKING') AS tracking FROM runs r"
           % ', '.join('r.' + c for c in schema.names('runs')))
    sql += (' WHERE ' + ' AND '.join(terms) if terms else '') + ' ORDER BY r.started_at'
    out, cols = db.query(sql, args)
    return [_clean(dict(zip(cols, r))) for r in out]


def run(db, run_id):
    """
    Return ``(run, alignments)`` of the run whose id is or starts with ``run_id``.

    :raises CatalogError: no such run, or the prefix names several.
    """
    found, cols = db.query('SELECT %s FROM runs WHERE run_id LIKE ? ORDER BY started_at'
                           % ', '.join(schema.names('runs')), (str(run_id) + '%',))
    if not found:
        raise CatalogError('no run %s in catalogue %s' % (run_id, db.name))
    if len(found) > 1:
        raise CatalogError('%d runs start with %s in catalogue %s: give more of the id'
                           % (len(found), run_id, db.name))
    r = _clean(dict(zip(cols, found[0])))
    rows, acols = db.query(ALIGNMENTS + ' WHERE a.run_id = ?' + ORDER, (r['run_id'],))
    return r, [_clean(dict(zip(acols, x))) for x in rows]


def columns(db, f=None):
    """
    Return the report's columns as arrays (one pass, no row dictionaries).

    ``machine``, ``final_state``, ``started_at`` (object arrays), ``final_loss_db``,
    ``time_to_peak_s`` (float, NaN for NULL), oldest first.
    """
    where, args = _where(f or Filters(), 'a.started_at')
    sql = ('SELECT r.machine, a.final_state, a.started_at, a.final_loss_db, a.time_to_peak_s '
           'FROM alignments a JOIN runs r ON a.run_id = r.run_id' + where + ORDER)
    rows, _ = db.query(sql, args)
    if not rows:
        empty = np.zeros(0)
        return dict(machine=empty.astype(object), final_state=empty.astype(object),
                    started_at=empty.astype(object), final_loss_db=empty,
                    time_to_peak_s=empty)
    machine, state, started, loss, ttp = zip(*rows)
    return dict(machine=np.array(machine, dtype=object),
                final_state=np.array(state, dtype=object),
                started_at=np.array(started, dtype=object),
                final_loss_db=np.array(loss, dtype=float),
                time_to_peak_s=np.array(ttp, dtype=float))
