# SPDX-License-Identifier: Apache-2.0
"""
Benchmark ``fiber-align runs report`` over a synthetic catalogue of 100,000 alignments.

The catalogue (SQLite, in a temporary folder) holds a week of three machines (``1d``,
``rig``, ``station``) at 20 alignments per run: final losses drawn around each machine's
level (station 2's drifting up through the week, a few faults without a loss), times to
peak around each machine's. ``runs report`` then runs in a fresh subprocess: its wall
time and peak memory (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss``: the whole
process, Python, numpy and matplotlib included). Goal: under 5 s.

``--real N`` builds, beside it, a catalogue of real offline runs: N seeds of each
machine's scenario (``switch`` on the 1-D machine: the alignment and its 5 switch cycles;
``align2d`` on the rig; ``station``), their rows made as ``simulate --catalog`` makes them,
their start times spread over a week, and writes its report (``--keep`` keeps it: the
figures a process engineer reads).

Usage: ``python -m bench.bench_records [--alignments N] [--keep DIR] [--usl-loss-db X]
[--real N] [--real-usl-loss-db X]``.
"""

import argparse
from pathlib import Path
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from fiber_align.records import backends, rows

MACHINES = {'1d': (0.020, 0.004, 0.08), 'rig': (0.030, 0.006, 0.11),
            'station': (0.060, 0.010, 2.2)}
PER_RUN = 20
WEEK_S = 7 * 86400.0
T0 = 1.8e9          # 2027-01-15 08:00 UTC


def make_catalogue(url, n, seed=0):
    """Write a week-like catalogue of ``n`` alignments; return the seconds it took."""
    rng = np.random.default_rng(seed)
    db = backends.connect(url)
    t_start = time.perf_counter()
    n_runs = n // PER_RUN
    names = list(MACHINES)
    batch = []
    for r in range(n_runs):
        machine = names[r % len(names)]
        mean, sd, ttp = MACHINES[machine]
        t0 = T0 + WEEK_S * r / n_runs
        run_id = 'bench-%06d' % r
        batch.append(('runs', rows.run_row(
            run_id, machine, 'realtime', False, {'bench': True}, rows.stamp(t0),
            rows.stamp(t0 + PER_RUN * 30.0), cycles_kept=PER_RUN * 30000, watchdog_trips=0,
            end_reason='stopped')))
        drift = 0.02 * (t0 - T0) / WEEK_S if machine == 'station' else 0.0
        for k in range(1, PER_RUN + 1):
            fault = rng.random() < 0.01
            loss = None if fault else float(abs(rng.normal(mean + drift, sd)))
            batch.append(('alignments', rows.alignment_row(
                run_id, k, 'part-%07d' % (r * PER_RUN + k), rows.stamp(t0 + 30.0 * k),
                rows.stamp(t0 + 30.0 * k + 5.0), 'FAULT' if fault else 'TRACKING', {},
                fault_reason='lost light' if fault else None, final_loss_db=loss,
                time_to_peak_s=float(ttp * rng.lognormal(0.0, 0.15)),
                time_to_first_light_s=float(ttp * 0.5), samples=int(ttp * 1000))))
        if len(batch) >= 5000:
            db.write(batch)
            batch = []
    db.write(batch)
    db.close()
    return time.perf_counter() - t_start


REAL = (('switch', '1d'), ('align2d', 'rig'), ('station', 'station'))


def make_real_catalogue(url, n_seeds):
    """Write the rows of ``n_seeds`` offline runs of each machine; return the seconds taken."""
    from fiber_align.simulation import alignment2d_scenarios, alignment_scenarios, \
        station_scenarios
    modules = {'switch': alignment_scenarios, 'align2d': alignment2d_scenarios,
               'station': station_scenarios}
    db = backends.connect(url)
    t_start = time.perf_counter()
    k = 0
    for seed in range(n_seeds):
        for scenario, machine in REAL:
            res = modules[scenario].run(scenario, seed=seed)
            t0 = T0 + WEEK_S * k / (n_seeds * len(REAL))
            k += 1
            run_id = 'real-%s-%03d' % (machine, seed)
            a, b = rows.stamp(t0), rows.stamp(t0 + 60.0)
            items = [('runs', rows.run_row(
                run_id, machine, 'offline', False, {'scenario': scenario, 'seed': seed}, a, b,
                cycles_kept=round(res['simulated_s'] * res['control_rate_hz']),
                watchdog_trips=0, end_reason=res.get('end_state')))]
            items += [('alignments', r) for r in rows.alignment_rows(
                res, run_id, 'part-%s-%03d' % (machine, seed), a, b)]
            db.write(items)
    db.close()
    return time.perf_counter() - t_start


def main(argv=None):
    """Build the catalogue, time the report in a subprocess; print a table; exit code."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--alignments', type=int, default=100_000)
    ap.add_argument('--usl-loss-db', type=float, default=0.06)
    ap.add_argument('--keep', default=None, help='keep the catalogue and report here')
    ap.add_argument('--real', type=int, default=0, metavar='N',
                    help='also a catalogue of N seeds of real offline runs per machine')
    ap.add_argument('--real-usl-loss-db', type=float, default=0.05)
    args = ap.parse_args(argv if argv is not None else [])
    tmp = Path(tempfile.mkdtemp(prefix='bench_records_'))
    try:
        url = str(tmp / 'catalog.db')
        build_s = make_catalogue(url, args.alignments)
        out = tmp / 'report'
        cmd = [sys.executable, '-m', 'fiber_align.cli', 'runs', 'report', '--catalog', url,
               '--usl-loss-db', str(args.usl_loss_db), '--out', str(out)]
        t = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        wall = time.perf_counter() - t
        peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
        print(proc.stdout.strip())
        if proc.returncode != 0:
            print(proc.stderr, file=sys.stderr)
            return 1
        print('| alignments | catalogue MB | build s | report wall s | report peak RSS MB | '
              'goal |')
        print('|---|---|---|---|---|---|')
        print('| %d | %.1f | %.1f | %.2f | %.0f | < 5 s: %s |' % (
            args.alignments, Path(url).stat().st_size / 1e6, build_s, wall, peak_mb,
            'met' if wall < 5.0 else 'MISSED'))
        if args.real:
            real = str(tmp / 'real.db')
            real_s = make_real_catalogue(real, args.real)
            proc = subprocess.run(
                [sys.executable, '-m', 'fiber_align.cli', 'runs', 'report', '--catalog', real,
                 '--usl-loss-db', str(args.real_usl_loss_db), '--out', str(tmp / 'real_report')],
                capture_output=True, text=True, timeout=300)
            print('\nreal offline runs: %d seeds x %d machines in %.0f s\n%s'
                  % (args.real, len(REAL), real_s, proc.stdout.strip()))
        if args.keep:
            shutil.copytree(tmp, args.keep, dirs_exist_ok=True)
        return 0 if wall < 5.0 else 1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
