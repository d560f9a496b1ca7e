# SPDX-License-Identifier: Apache-2.0
"""
Full-size alignment checks at 1 kHz through the composite loop (docs/alignment.md).

- 20 slots across the reachable range, one noise seed each: aligned within 0.05 dB in
  <= 0.5 s and <= 60 peak samples; every failure a FAULT with a reason.
- 60 s of TRACKING under 1 um/s drift: largest loss against the moving maximum.
- 1,000 switch cycles: largest 10-90 % optical rise and drift of the loss.
- A broken fiber and a slot outside the range: the FAULT reasons.

``python -m bench bench_alignment`` (add ``--quick`` via ``main(['--quick'])`` for a
reduced run). Takes about a minute on one core.
"""

import argparse
import sys
import time

from fiber_align.simulation import alignment_bench as ab, alignment_scenarios as sc


def main(argv=None):
    """Run the checks and print a table; return 0."""
    ap = argparse.ArgumentParser(prog='bench_alignment')
    ap.add_argument('--quick', action='store_true', help='reduced sizes')
    ap.add_argument('--loop', default='composite', help='composite or ideal')
    args = ap.parse_args([] if argv is None else argv)
    n_cycles, track_s = (50, 5.0) if args.quick else (1000, 60.0)
    loop = ab.make_loop(args.loop)
    t0 = time.time()
    trials, s = sc.align_trials(20, seed=0, loop=loop)
    print('| slot (um) | state | loss (dB) | time to light (ms) | time to peak (ms) '
          '| peak samples |')
    print('|---|---|---|---|---|---|')
    for r in trials:
        def f(v, scale=1.0, fmt='%.1f'):
            return '-' if v is None else fmt % (v * scale)
        print('| %.1f | %s | %s | %s | %s | %s |'
              % (r['slot_m'] * 1e6, r['state'] if r['aligned'] else
                 '%s (%s)' % (r['state'], r['fault_reason']),
                 f(r['final_loss_db'], fmt='%.4f'), f(r['time_to_first_light_s'], 1e3),
                 f(r['time_to_peak_s'], 1e3), f(r['peak_samples'], fmt='%d')))
    print('\naligned %d/20, silent failures %d, worst loss %.4f dB, worst time to peak '
          '%.1f ms, most peak samples %d'
          % (s['aligned'], s['silent_failures'], s['max_final_loss_db'],
             s['max_time_to_peak_s'] * 1e3, s['max_peak_samples']))
    r = sc.run('track', seed=1, loop=loop, duration_s=track_s, drift_m_per_s=1e-6)
    print('track %.0f s at 1 um/s: max loss %.4f dB, mean %.4f dB, end state %s'
          % (r['tracking_time_s'], r['tracking_max_loss_db'], r['tracking_mean_loss_db'],
             r['tracking_state']))
    r = sc.run('switch', seed=2, loop=loop, slot_m=40e-6, cycles=n_cycles)
    print('switch %d cycles (slot 40 um): rise 10-90%% max %.2f ms, median %.2f ms; loss '
          'first %.4f dB, last %.4f dB, drift %+.4f dB, max %.4f dB, faults %s'
          % (r['cycles'], r['switch_rise_time_s'] * 1e3,
             r['switch_rise_time_median_s'] * 1e3, r['cycle_loss_first_db'],
             r['cycle_loss_last_db'], r['cycle_loss_drift_db'], r['cycle_loss_max_db'],
             r['switch_faults'] or 'none'))
    rises = []
    for slot in (10e-6, 25e-6, 45e-6, 55e-6, 64e-6):
        q = sc.run('switch', seed=3, loop=loop, slot_m=slot, cycles=3)
        rises.append('%.0f um: %.2f ms' % (slot * 1e6, q['switch_rise_time_s'] * 1e3))
    print('switch rise by slot: ' + ', '.join(rises))
    r = sc.run('align', seed=3, loop=loop, slot_m=30e-6, fiber_broken=True)
    print('broken fiber: %s after %.0f ms: %s'
          % (r['state'], (r['simulated_s'] - 0.02) * 1e3, r['fault_reason']))
    r = sc.run('align', seed=3, loop=loop, slot_m=72e-6)
    print('slot at 72 um: %s: %s' % (r['state'], r['fault_reason']))
    print('(%.0f s wall)' % (time.time() - t0))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
