# SPDX-License-Identifier: Apache-2.0
"""
The fiber array offline at 1 kHz, composite control on all three actuators, noise on.

Seeds 0..19 (docs/array.md): the chip's pose drawn over the stroke (roll within +-12 mrad),
the waveguides' errors and the channels' gains drawn per seed; align from IDLE with the
joint method and, on the same chip and seeds, with the serial baseline. Per seed and
summed up: the worst channel's loss against the best joint pose (goal <= 0.1 dB on every
seed), the time to aligned (command to TRACKING, first light included; goal <= 1 s) and
the samples in that time (goal: median <= 0.5 x the serial baseline's).

``python -m bench bench_array``; ``main(['--quick'])`` runs 3 seeds (for tests of the
bench itself); ``python bench/bench_array.py --seeds 50`` runs seeds 0..49.
"""

import argparse
import sys
import time

import numpy as np

from fiber_align.alignment.states import TRACKING
from fiber_align.simulation import array_scenarios as sc

GOAL_LOSS_DB, GOAL_TIME_S, GOAL_RATIO = 0.1, 1.0, 0.5


def _f(v, scale=1.0, fmt='%.1f'):
    return '-' if v is None else fmt % (v * scale)


def _cell(q):
    if q['state'] != TRACKING:
        return '%s: %s' % (q['state'], q['fault_reason'])
    return '%s / %s / %d' % (_f(q['worst_channel_loss_db'], fmt='%.4f'),
                             _f(q['time_to_aligned_s'], 1e3, '%.0f'), q['samples'])


def table(rig, seeds):
    """Align both methods for every seed; print the table and the summary; return rows."""
    rows = []
    print('| seed | chip x, y (um), roll (mrad) | joint: worst-channel loss dB / time ms / '
          'samples | serial: loss dB / time ms / samples | samples ratio |')
    print('|---|---|---|---|---|')
    for seed in seeds:
        r = sc.run('array', seed=seed, rig=rig)
        rows.append(r)
        b = r['baseline']
        ratio = (r['samples'] / b['samples']) if r['samples'] and b['samples'] else None
        print('| %d | %.1f, %.1f, %+.2f | %s | %s | %s |' % (
            seed, r['true']['x_m'] * 1e6, r['true']['y_m'] * 1e6, r['true']['roll_rad'] * 1e3,
            _cell(r), _cell(b), _f(ratio, fmt='%.2f')))
    med = {}
    for label, get in (('joint', lambda r: r), ('serial', lambda r: r['baseline'])):
        qs = [get(r) for r in rows]
        ok = [q for q in qs if q['state'] == TRACKING]
        loss = [q['worst_channel_loss_db'] for q in ok]
        tt = [q['time_to_aligned_s'] for q in ok]
        ss = [q['samples'] for q in ok]
        med[label] = float(np.median(ss)) if ss else None
        print('\n%s: %d/%d TRACKING, %d/%d within %.1f dB; worst-channel loss median %s dB, '
              'worst %s dB; time to aligned median %s ms, worst %s ms; samples median %s, '
              'worst %s' % (label, len(ok), len(qs),
                            sum(1 for v in loss if v <= GOAL_LOSS_DB), len(qs), GOAL_LOSS_DB,
                            _f(np.median(loss) if loss else None, fmt='%.4f'),
                            _f(max(loss, default=None), fmt='%.4f'),
                            _f(np.median(tt) if tt else None, 1e3, '%.0f'),
                            _f(max(tt, default=None), 1e3, '%.0f'),
                            _f(med[label], fmt='%.0f'), _f(max(ss, default=None), fmt='%d')))
    good = all(r['state'] == TRACKING and r['worst_channel_loss_db'] <= GOAL_LOSS_DB
               and r['time_to_aligned_s'] <= GOAL_TIME_S for r in rows)
    ratio = med['joint'] / med['serial'] if med['joint'] and med['serial'] else None
    print('joint / serial samples, median / median: %s (goal <= %.1f); every seed within '
          '%.1f dB and %.0f s: %s'
          % (_f(ratio, fmt='%.2f'), GOAL_RATIO, GOAL_LOSS_DB, GOAL_TIME_S,
             'yes' if good else 'NO'))
    return rows


def main(argv=None):
    """Run the seeds and print the table; return 0."""
    ap = argparse.ArgumentParser(prog='bench_array')
    ap.add_argument('--quick', action='store_true', help='3 seeds')
    ap.add_argument('--seeds', type=int, default=20, help='seeds 0..N-1 (default 20)')
    args = ap.parse_args([] if argv is None else argv)
    t0 = time.process_time()
    rig = sc.ArrayRig('composite', 1e-3, 0)
    table(rig, range(3 if args.quick else args.seeds))
    print('(%.0f s CPU)' % (time.process_time() - t0))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
