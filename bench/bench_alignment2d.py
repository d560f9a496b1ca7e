# SPDX-License-Identifier: Apache-2.0
"""
Two-axis alignment at 1 kHz, composite control on each axis, noise on (docs/alignment2d.md).

Every figure is measured for the 2-D sequencer and, in the same run on the same rig,
targets and noise seeds, for the coordinate hill-climb baseline:

- align from IDLE, target at 20 random points of the reachable square (one per cell of a
  5 x 4 grid, so the whole square is covered), seeds 0..19: within 0.05 dB of the true peak,
  <= 1 s, <= 150 peak samples; ratios hill climb / sequencer of samples and time;
- tracking 60 s (three seeds), target drifting at 1 um/s in a random direction and
  vibrating 0.2 um at 30 Hz in a random direction: loss after the first second;
- 1,000 switch off/on cycles (30 ms off, 60 ms on): loss at the end of each on period;
- faults: broken fiber, target out of reach in x and in y, fiber breaking while tracking.

``python -m bench bench_alignment2d`` (``main(['--quick'])`` for a reduced run;
``python bench/bench_alignment2d.py --extra 200`` aligns the sequencer alone to 200 more
random targets).
"""

import argparse
import sys
import time

import numpy as np

from fiber_align.simulation import alignment2d_scenarios as sc
from fiber_align.alignment import sequencer2d as s2d


def targets(n_x=5, n_y=4, seed=14):
    """Return one uniform random target (m) in each cell of an ``n_x`` by ``n_y`` grid."""
    seq = s2d.Sequencer2D(period_s=sc.graph_period_s())
    rng = np.random.default_rng(seed)
    ex = np.linspace(seq.lo[0], seq.hi[0], n_x + 1)
    ey = np.linspace(seq.lo[1], seq.hi[1], n_y + 1)
    return [(float(rng.uniform(ex[i], ex[i + 1])), float(rng.uniform(ey[j], ey[j + 1])))
            for j in range(n_y) for i in range(n_x)]


def _f(v, scale=1.0, fmt='%.1f'):
    return '-' if v is None else fmt % (v * scale)


def align_table(rig, n_x=5, n_y=4):
    """Align both methods to every target; print the table; return the rows."""
    rows = []
    print('| # | target (um) | sequencer: loss dB / time ms / peak samples / all samples '
          '| hill climb: loss dB / time ms / peak samples / all samples |')
    print('|---|---|---|---|')
    for i, tg in enumerate(targets(n_x, n_y)):
        r = sc.run('align2d', seed=i, rig=rig, target=tg)
        rows.append(r)
        cells = []
        for q in (r, r['baseline']):
            if q['state'] != s2d.TRACKING:
                cells.append('%s: %s' % (q['state'], q['fault_reason']))
            else:
                cells.append('%s / %s / %d / %d%s' % (
                    _f(q['final_loss_db'], fmt='%.4f'), _f(q['time_to_peak_s'], 1e3),
                    q['peak_samples'], q['samples'], '' if q['aligned'] else ' (missed)'))
        print('| %d | (%.1f, %.1f) | %s | %s |' % (i, tg[0] * 1e6, tg[1] * 1e6, *cells))
    for label, get in (('sequencer', lambda r: r), ('hill climb', lambda r: r['baseline'])):
        qs = [get(r) for r in rows]
        ok = [q for q in qs if q['aligned']]
        tr = [q for q in qs if q['state'] == s2d.TRACKING]
        print('\n%s: %d/%d within 0.05 dB in <= 1 s with <= 150 peak samples; %d/%d with '
              '<= 150 samples counting the search too; worst loss %s dB, worst time %s ms, '
              'most peak samples %s, most samples %s; median time %s ms, median peak '
              'samples %s' % (
                  label, len(ok), len(qs), sum(1 for q in ok if q['samples'] <= 150),
                  len(qs), _f(max((q['final_loss_db'] for q in tr), default=None), fmt='%.4f'),
                  _f(max((q['time_to_peak_s'] for q in tr), default=None), 1e3),
                  max((q['peak_samples'] for q in tr), default='-'),
                  max((q['samples'] for q in tr), default='-'),
                  _f(np.median([q['time_to_peak_s'] for q in tr]) if tr else None, 1e3),
                  _f(np.median([q['peak_samples'] for q in tr]) if tr else None, fmt='%.0f')))
        print('  each goal alone: %d/%d within 0.05 dB, %d/%d in <= 1 s, %d/%d with <= 150 '
              'peak samples' % (
                  sum(1 for q in tr if q['final_loss_db'] <= 0.05), len(qs),
                  sum(1 for q in tr if q['time_to_peak_s'] <= 1.0), len(qs),
                  sum(1 for q in tr if q['peak_samples'] <= 150), len(qs)))
    both = [r for r in rows if r['state'] == r['baseline']['state'] == s2d.TRACKING]
    if both:
        ps = sum(r['baseline']['peak_samples'] for r in both) / sum(
            r['peak_samples'] for r in both)
        ts = sum(r['baseline']['time_to_peak_s'] for r in both) / sum(
            r['time_to_peak_s'] for r in both)
        pr = [r['samples_ratio'] for r in both]
        tt = [r['time_ratio'] for r in both]
        print('ratio hill climb / sequencer over the %d cases both aligned: peak samples %.2f '
              '(per case %.2f..%.2f), time to peak %.2f (per case %.2f..%.2f)'
              % (len(both), ps, min(pr), max(pr), ts, min(tt), max(tt)))
    return rows


def extra_targets(rig, n):
    """Align the sequencer to ``n`` uniform random targets, seeds 100..; print a summary."""
    qs = [sc.run_method('align2d', 'sequencer', seed=100 + i, rig=rig) for i in range(n)]
    ok = [q for q in qs if q['aligned']]
    print('sequencer, %d random targets (seeds 100..%d): %d aligned (<= 0.05 dB, <= 1 s, '
          '<= 150 peak samples); worst loss %s dB, worst time %s ms, most peak samples %s, '
          'most samples %s, %d with more than 150 samples counting the search; failures %s'
          % (n, 99 + n, len(ok), _f(max((q['final_loss_db'] for q in ok), default=None),
                                    fmt='%.4f'),
             _f(max((q['time_to_peak_s'] for q in ok), default=None), 1e3),
             max((q['peak_samples'] for q in ok), default='-'),
             max((q['samples'] for q in ok), default='-'),
             sum(1 for q in ok if q['samples'] > 150),
             [(q['target_x_m'], q['target_y_m'], q['state'], q['fault_reason'])
              for q in qs if not q['aligned']] or 'none'))
    return 0


def main(argv=None):
    """Run the checks and print the tables; return 0."""
    ap = argparse.ArgumentParser(prog='bench_alignment2d')
    ap.add_argument('--quick', action='store_true', help='reduced sizes')
    ap.add_argument('--extra', type=int, default=0, metavar='N',
                    help='only align the sequencer to N more random targets (seeds 100..)')
    args = ap.parse_args([] if argv is None else argv)
    n_cycles, track_s = (50, 5.0) if args.quick else (1000, 60.0)
    t0 = time.time()
    rig = sc.Rig2D('composite', 1e-3, 0)
    if args.extra:
        return extra_targets(rig, args.extra)
    align_table(rig)
    print()
    for seed in (1, 2, 3):
        r = sc.run('track2d', seed=seed, rig=rig, duration_s=track_s)
        for label, q in (('sequencer', r), ('hill climb', r['baseline'])):
            if q.get('tracking_max_loss_db') is None:
                print('track, %s: %s %s' % (label, q['end_state'], q['end_fault_reason']))
                continue
            print('track %.0f s (seed %d: 1 um/s drift, 0.2 um 30 Hz vibration), %s: after '
                  'the first second max loss %.4f dB, 99th percentile %.4f dB, mean %.4f dB, '
                  'end %s %s' % (track_s, seed, label, q['tracking_max_loss_db'],
                                 q['tracking_p99_loss_db'], q['tracking_mean_loss_db'],
                                 q['end_state'], q['end_fault_reason']))
    r = sc.run('switch2d', seed=2, rig=rig, cycles=n_cycles)
    for label, q in (('sequencer', r), ('hill climb', r['baseline'])):
        if not q.get('cycles'):
            print('switch, %s: %s %s' % (label, q['end_state'], q['end_fault_reason']))
            continue
        print('switch %d cycles (30 ms off, 60 ms on), %s: loss at the end of each on period '
              'max %.4f dB, first 10 %.4f dB, last 10 %.4f dB, drift %+.4f dB, over 0.05 dB '
              '%d, not yet tracking %d, faults %s'
              % (q['cycles'], label, q['cycle_loss_max_db'], q['cycle_loss_first_db'],
                 q['cycle_loss_last_db'], q['cycle_loss_drift_db'], q['cycles_over_goal'],
                 q['cycles_not_tracking'], q['switch_faults'] or 'none'))
    print()
    for what, tg, kw in (('broken fiber', (30e-6, 30e-6), dict(fiber_broken=True)),
                         ('target at x 75 um', (75e-6, 30e-6), {}),
                         ('target at y -8 um', (30e-6, -8e-6), {})):
        for method in sc.METHODS:
            b = sc.build(3, method=method, target=tg, rig=rig, **kw)
            q = sc.align_bench(b)
            print('%s, %s: %s after %.0f ms: %s'
                  % (what, method, q['state'], (b.t - 0.02) * 1e3, q['fault_reason']))
    b = sc.build(4, target=(40e-6, 20e-6), rig=rig)
    sc.align_bench(b)
    t_break = b.t
    b.link.coupling.fiber_broken = True
    b.run_until(b.t + 0.2, lambda x: x.seq.state == s2d.FAULT)
    print('fiber breaks while tracking: %s after %.0f ms: %s'
          % (b.seq.state, (b.t - t_break) * 1e3, b.seq.fault_reason))
    print('(%.0f s wall)' % (time.time() - t0))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
