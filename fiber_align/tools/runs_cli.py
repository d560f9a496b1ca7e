# SPDX-License-Identifier: Apache-2.0
"""
``fiber-align runs``: read the run catalogue (docs/records.md), and ``simulate``'s records.

``runs list`` (filters: ``--part``, ``--machine``, ``--since``/``--until``, ``--state``;
``--alignments`` lists alignments instead of runs; ``--json``), ``runs show RUN``,
``runs export --csv FILE`` and ``runs report --usl-loss-db X --out DIR``. The catalogue
is ``--catalog URL`` (default: ``catalog`` in ``config/records.yaml``). :func:`recorder`
is ``fiber-align simulate --catalog URL --part P``'s writer of the run and its alignments.
"""

import csv
import json
import os
import sys
import time

from fiber_align.config import load_params
from fiber_align.jsonout import json_clean
from fiber_align.records import backends, query, report, rows as rowlib
from fiber_align.records.schema import CatalogError
from fiber_align.records.writer import CatalogWriter
from fiber_align.simulation import scenarios
from fiber_align.tools.common import UsageError

CONFIG = ('records.yaml', 'run_catalog')
#: The catalogue's machine of each scenario family (:data:`scenarios.MACHINE_SCENARIOS`);
#: the names of ``fiber_align.graph.machines.MACHINES``.
MACHINE_OF_FAMILY = {'one': '1d', 'rig': 'rig', 'station': 'station'}
#: How long ``simulate`` waits for its rows to be written at its end, s.
FLUSH_S = 10.0


def params():
    """Return the catalogue's parameters (``config/records.yaml``)."""
    return load_params(*CONFIG)


def _filters(p):
    p.add_argument('--catalog', default=None,
                   help='catalogue URL: default, a SQLite path, sqlite:///path or '
                        'postgresql://... (default: catalog in config/records.yaml)')
    p.add_argument('--part', default=None, help='part_id')
    p.add_argument('--machine', default=None, help='1d | rig | station | ...')
    p.add_argument('--since', default=None, help='from this UTC date/time (YYYY-MM-DD)')
    p.add_argument('--until', default=None, help='up to this UTC date (whole day) or time')
    p.add_argument('--state', default=None, help='final state (TRACKING, FAULT, ...)')


def register(sub):
    """Add the ``runs`` sub-command and its four actions."""
    p = sub.add_parser('runs', help='the run catalogue: list, show, export, report')
    acts = p.add_subparsers(dest='action', metavar='ACTION')
    q = acts.add_parser('list', help='runs (or --alignments) the filters keep')
    _filters(q)
    q.add_argument('--alignments', action='store_true', help='one line per alignment')
    q.add_argument('--json', action='store_true', help='print JSON rows')
    q.set_defaults(func=cmd_list, paths={})
    q = acts.add_parser('show', help='one run and its alignments')
    q.add_argument('run', metavar='RUN', help='run_id (or its first characters)')
    q.add_argument('--catalog', default=None, help='catalogue URL (see runs list)')
    q.add_argument('--json', action='store_true', help='print JSON')
    q.set_defaults(func=cmd_show, paths={})
    q = acts.add_parser('export', help='the alignments as CSV')
    _filters(q)
    q.add_argument('--csv', required=True, help='CSV file to write')
    q.set_defaults(func=cmd_export, paths={'--csv': 'out-file'})
    q = acts.add_parser('report', help='yield, Cpk/Ppk, histograms, I-MR charts')
    _filters(q)
    q.add_argument('--usl-loss-db', type=float, required=True,
                   help='upper specification limit of the final loss, dB')
    q.add_argument('--out', required=True, help='folder for report.md and the PNGs')
    q.set_defaults(func=cmd_report, paths={'--out': 'out-dir'})
    p.set_defaults(func=lambda args: _usage(p))


def _usage(p):
    p.print_help()
    return 2


def _open(args):
    url = args.catalog or params()['catalog']
    if backends.parse(url) is None:
        raise UsageError('the catalogue is off (%s): give --catalog URL' % url)
    try:
        return backends.connect(url, create=False, **_timeouts())
    except CatalogError as exc:
        raise UsageError(str(exc)) from None


def _timeouts():
    p = params()
    return dict(connect_timeout_s=p['connect_timeout_s'], busy_timeout_s=p['busy_timeout_s'])


def _f(args):
    for name in ('since', 'until'):
        v = getattr(args, name)
        if v is not None:
            rowlib.parse_stamp(v)       # a ValueError: one line, exit 2
    return query.Filters(part=args.part, machine=args.machine, since=args.since,
                         until=args.until, state=args.state)


def _fmt(v, fmt, scale=1.0):
    return '-' if v is None else fmt % (v * scale)


def cmd_list(args):
    """Run ``runs list``; return an exit code."""
    db = _open(args)
    try:
        got = (query.alignments if args.alignments else query.runs)(db, _f(args))
    finally:
        db.close()
    if args.json:
        print(json.dumps(json_clean(got), indent=1, sort_keys=True))
        return 0
    if args.alignments:
        print('run_id                               seq part         machine  started_at'
              '                  final_state  loss dB  peak ms')
        for a in got:
            print('%-36s %3d %-12s %-8s %-27s %-12s %8s %8s' % (
                a['run_id'], a['seq'], a['part_id'] or '-', a['machine'], a['started_at'],
                a['final_state'], _fmt(a['final_loss_db'], '%.4f'),
                _fmt(a['time_to_peak_s'], '%.1f', 1e3)))
    else:
        print('run_id                               started_at                  machine  '
              'sync      alignments tracking end_reason')
        for r in got:
            print('%-36s %-27s %-8s %-9s %10d %8d %s' % (
                r['run_id'], r['started_at'], r['machine'], r['sync_mode'], r['alignments'],
                r['tracking'], r['end_reason'] or '-'))
    print('%d %s' % (len(got), 'alignments' if args.alignments else 'runs'), file=sys.stderr)
    return 0


def cmd_show(args):
    """Run ``runs show RUN``; return an exit code."""
    db = _open(args)
    try:
        run, aligns = query.run(db, args.run)
    except CatalogError as exc:
        raise UsageError(str(exc)) from None
    finally:
        db.close()
    if args.json:
        print(json.dumps(json_clean(dict(run=run, alignments=aligns)), indent=1,
                         sort_keys=True))
        return 0
    for k, v in run.items():
        print('%-16s %s' % (k, json.dumps(v, sort_keys=True) if isinstance(v, (dict, list))
                            else v))
    for a in aligns:
        print('  seq %d part %s: %s%s, loss %s dB, first light %s ms, peak %s ms, %s samples'
              % (a['seq'], a['part_id'], a['final_state'],
                 ' (%s)' % a['fault_reason'] if a['fault_reason'] else '',
                 _fmt(a['final_loss_db'], '%.4f'), _fmt(a['time_to_first_light_s'], '%.1f',
                                                        1e3),
                 _fmt(a['time_to_peak_s'], '%.1f', 1e3), _fmt(a['samples'], '%d')))
    return 0


def cmd_export(args):
    """Run ``runs export --csv FILE``; return an exit code."""
    db = _open(args)
    try:
        got = query.alignments(db, _f(args))
    finally:
        db.close()
    with open(args.csv, 'w', newline='', encoding='utf-8') as f:
        w = csv.writer(f)
        w.writerow(query.EXPORT_COLUMNS)
        for a in got:
            w.writerow(['' if a[c] is None else json.dumps(a[c], sort_keys=True)
                        if isinstance(a[c], (dict, list)) else a[c]
                        for c in query.EXPORT_COLUMNS])
    print('%d alignments -> %s' % (len(got), args.csv), file=sys.stderr)
    return 0


def cmd_report(args):
    """Run ``runs report``; return an exit code."""
    db = _open(args)
    try:
        cols = query.columns(db, _f(args))
        title = 'Alignment report: %s' % db.name
    finally:
        db.close()
    table = report.write(cols, args.usl_loss_db, args.out, title)
    for name, s in table.items():
        print('%-8s %7d alignments, yield %s %%, Cpk %s, Ppk %s' % (
            name, s['n'], _fmt(s['yield'], '%.2f', 100.0), _fmt(s['cpk'], '%.2f'),
            _fmt(s['ppk'], '%.2f')))
    print('report: %s' % os.path.join(args.out, 'report.md'))
    return 0


def add_simulate_options(p):
    """Add ``--catalog`` and ``--part`` to ``simulate``."""
    g = p.add_argument_group('catalogue (docs/records.md; alignment scenarios)')
    g.add_argument('--catalog', default=None,
                   help='record the run and its alignments: default, a SQLite path, '
                        'sqlite:///path, postgresql://... or none')
    g.add_argument('--part', default=None, help='part_id of the alignments')


def recorder(args):
    """
    Return ``(on_result, finish)`` for ``simulate --catalog``, or None without it.

    ``on_result(result)`` queues the run's and its alignments' rows; ``finish()`` waits
    up to :data:`FLUSH_S` for them (less once a try of the catalogue failed: they are
    in the spool then) and writes one line on stderr if they wait in the spool (the
    run's exit code stands).
    """
    if args.catalog is None:
        if args.part is not None:
            raise UsageError('--part needs --catalog')
        return None
    try:
        if backends.parse(args.catalog) is None:
            return None
    except CatalogError as exc:
        raise UsageError(str(exc)) from None
    family = next((f for f, names in scenarios.MACHINE_SCENARIOS.items()
                   if args.scenario in names), None)
    if family is None:
        raise UsageError('--catalog records alignments: --scenario %s has none (use %s)'
                         % (args.scenario, ', '.join(scenarios.ALIGNMENT)))
    writer = CatalogWriter(args.catalog, params())
    run_id, t0 = rowlib.new_run_id(), rowlib.stamp()
    keys = ('scenario', 'seed', 'loop', 'rate', 'cycles', 'duration', 'slot', 'drift')

    def on_result(result):
        t1 = rowlib.stamp()
        rate = result.get('control_rate_hz')
        periods = round(result['simulated_s'] * rate) if rate and \
            result.get('simulated_s') is not None else None
        writer.put('runs', rowlib.run_row(
            run_id, MACHINE_OF_FAMILY[family], 'offline', False,
            {k: getattr(args, k, None) for k in keys}, t0, t1, cycles_kept=periods,
            watchdog_trips=0, end_reason=result.get('end_state') or result.get('state')))
        for row in rowlib.alignment_rows(result, run_id, args.part, t0, t1):
            writer.put('alignments', row)

    def finish():
        start = time.monotonic()
        writer.flush(FLUSH_S, until_refused=True)
        s = writer.close(max(0.1, FLUSH_S - (time.monotonic() - start)))
        if s['level'] != 'ok':
            print('fiber-align simulate: warning: run %s not in the catalogue yet: %s (%d '
                  'rows wait in %s)' % (run_id, s['reason'], s['spooled'], writer.spool),
                  file=sys.stderr)
        else:
            print('catalogue %s: run %s' % (writer.name, run_id), file=sys.stderr)
    return on_result, finish
