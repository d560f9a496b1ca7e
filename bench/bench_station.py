# SPDX-License-Identifier: Apache-2.0
"""
The coupled station offline at 1 kHz, composite control on all four axes, noise on.

Every figure beside its baseline in the same run (docs/station.md):

- align from IDLE, both facets 2-20 um off the nominal positions on all four axes (random
  signs), seeds 0..19: how many within 0.05 dB of the true joint peak, for the concurrent
  method and for the serial baseline on the same facets and seeds; the peak samples
  (readings from first light to TRACKING) of both, median and worst, and their ratio;
- cure, seeds 0..9: each fiber pulled 0.5-2 um in a random direction over 10-60 s; the
  largest loss with tracking on, beside the same drifts with tracking off.

``python -m bench bench_station``; ``main(['--quick'])`` runs 3 align seeds and 2 cure
seeds with the cure shortened to 3 s (for tests of the bench itself);
``python bench/bench_station.py --extra 50`` aligns both methods for seeds 20..69.
"""

import argparse
import sys
import time

import numpy as np

from fiber_align.alignment.states import TRACKING
from fiber_align.simulation import station_scenarios as sc


def _f(v, scale=1.0, fmt='%.1f'):
    return '-' if v is None else fmt % (v * scale)


def align_table(rig, seeds):
    """Align both methods for every seed; print the table; return the rows."""
    rows = []
    print('| seed | facets (um) | concurrent: loss dB / first light ms / peak samples | '
          'serial: loss dB / first light ms / peak samples | ratio |')
    print('|---|---|---|---|---|')
    for seed in seeds:
        r = sc.run('station', seed=seed, rig=rig)
        rows.append(r)
        cells = []
        for q in (r, r['baseline']):
            if q['state'] != TRACKING:
                cells.append('%s: %s' % (q['state'], q['fault_reason']))
            else:
                cells.append('%s / %s / %d' % (_f(q['final_loss_db'], fmt='%.4f'),
                                               _f(q['time_to_first_light_s'], 1e3),
                                               q['peak_samples']))
        print('| %d | (%s) | %s | %s | %s |' % (
            seed, ', '.join('%.1f' % (v * 1e6) for v in r['facets_m']), *cells,
            _f(r['samples_ratio'], fmt='%.2f')))
    summary = {}
    for label, get in (('concurrent', lambda r: r), ('serial', lambda r: r['baseline'])):
        qs = [get(r) for r in rows]
        ok = [q for q in qs if q['aligned']]
        ps = [q['peak_samples'] for q in qs if q['state'] == TRACKING]
        fl = [q['time_to_first_light_s'] for q in qs if q['time_to_first_light_s'] is not None]
        summary[label] = (np.median(ps) if ps else None, max(ps) if ps else None)
        print('\n%s: %d/%d within 0.05 dB of the true joint peak; worst loss %s dB; peak '
              'samples median %s, worst %s; first light median %s ms, worst %s ms'
              % (label, len(ok), len(qs),
                 _f(max((q['final_loss_db'] for q in qs if q['final_loss_db'] is not None),
                        default=None), fmt='%.4f'),
                 _f(summary[label][0], fmt='%.0f'), _f(summary[label][1], fmt='%d'),
                 _f(np.median(fl) if fl else None, 1e3), _f(max(fl, default=None), 1e3)))
    both = [r for r in rows if r['aligned'] and r['baseline']['aligned']]
    if both:
        rr = [r['samples_ratio'] for r in both]
        (cm, cw), (sm, sw) = summary['concurrent'], summary['serial']
        print('concurrent / serial peak samples over the %d seeds both aligned: per seed '
              'median %.2f, worst %.2f; median / median %.2f, worst / worst %.2f'
              % (len(both), float(np.median(rr)), max(rr), cm / sm, cw / sw))
    return rows


def cure_table(rig, seeds, quick=False):
    """Run the cure for every seed; print tracked beside untracked; return the rows."""
    rows = []
    print('| seed | pull in / out (um) | duration in / out (s) | tracked max / final dB | '
          'untracked max / final dB |')
    print('|---|---|---|---|---|')
    kw = {}
    for seed in seeds:
        if quick:
            kw = dict(cure_duration_s=3.0)
        r = sc.run('cure', seed=seed, rig=rig, **kw)
        rows.append(r)
        if r.get('max_loss_db') is None:
            print('| %d | %s %s |' % (seed, r['end_state'], r['end_fault_reason']))
            continue
        print('| %d | %.2f / %.2f | %.1f / %.1f | %.4f / %.4f | %.4f / %.4f |' % (
            seed, r['cure_in_amplitude_m'] * 1e6, r['cure_out_amplitude_m'] * 1e6,
            r['cure_in_duration_s'], r['cure_out_duration_s'], r['max_loss_db'],
            r['final_loss_db'], r['untracked_max_loss_db'], r['untracked_final_loss_db']))
    ok = [r for r in rows if r.get('max_loss_db') is not None]
    if ok:
        print('\ncure, %d seeds: tracked max loss worst %.4f dB (%d/%d <= 0.1 dB), ended %s; '
              'untracked final loss %.3f..%.3f dB'
              % (len(rows), max(r['max_loss_db'] for r in ok),
                 sum(1 for r in ok if r['max_loss_db'] <= 0.1), len(rows),
                 sorted({r['end_state'] for r in ok}),
                 min(r['untracked_final_loss_db'] for r in ok),
                 max(r['untracked_final_loss_db'] for r in ok)))
    return rows


def main(argv=None):
    """Run the checks and print the tables; return 0."""
    ap = argparse.ArgumentParser(prog='bench_station')
    ap.add_argument('--quick', action='store_true', help='reduced sizes')
    ap.add_argument('--extra', type=int, default=0, metavar='N',
                    help='only align both methods for N more seeds (20..19+N)')
    args = ap.parse_args([] if argv is None else argv)
    t0 = time.process_time()
    rig = sc.StationRig('composite', 1e-3, 0)
    if args.extra:
        align_table(rig, range(20, 20 + args.extra))
        print('(%.0f s CPU)' % (time.process_time() - t0))
        return 0
    align_table(rig, range(3) if args.quick else range(20))
    print()
    cure_table(rig, range(2) if args.quick else range(10), quick=args.quick)
    print('(%.0f s CPU)' % (time.process_time() - t0))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
