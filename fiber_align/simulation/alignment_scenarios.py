# SPDX-License-Identifier: Apache-2.0
"""
Offline alignment scenarios: the sequencer as the setpoint source of a closed loop.

One control period ``k`` (docs/CONTRACTS.md): the loop's measurement ``y_k`` (m) and the
detector reading ``P_k`` (W, from the true tip position at ``t_k``) go to
``Sequencer.update(t_k, y_k, P_k)``, whose setpoint ``r_k`` (m) drives the loop for one
period. Scenarios (``run(name, seed, **kw)`` returns a dict of SI metrics):

``align``
    From IDLE, ``align`` with the slot at a random position in the reachable range
    (``slot_m`` fixes it); metrics ``time_to_first_light_s``, ``time_to_peak_s``,
    ``final_loss_db`` (true loss against the true maximum, mean over the first
    ``loss_window_s`` of TRACKING), ``peak_samples``.
``switch``
    Align, then ``cycles`` switch off/on cycles; ``switch_rise_time_s`` is the largest
    10-90 % rise of the measured optical power over the cycles, ``cycle_loss_db`` the
    loss at the end of each on period.
``track``
    Align with the slot near the bottom of the range, then track a slot drifting at
    ``drift_m_per_s`` for ``duration_s``; ``tracking_max_loss_db`` is the largest true
    loss (dither included) while TRACKING.

Loops (``loop=``): ``composite`` (default: the control core's plant, feedforward and
fuzzy PID) or ``ideal`` (a first-order stand-in, fast, for tests); see
:mod:`fiber_align.simulation.alignment_bench`.
"""

import json
import sys

import numpy as np

from fiber_align.alignment import sequencer as sq
from fiber_align.alignment.plots import plot_run
from fiber_align.config import load_params
from fiber_align.jsonout import json_clean
from fiber_align.simulation.alignment_bench import build, true_loss

SCENARIOS = ('align', 'switch', 'track')
METRIC_KEYS = ('time_to_first_light_s', 'time_to_peak_s', 'final_loss_db', 'peak_samples',
               'switch_rise_time_s', 'tracking_max_loss_db')


def align_bench(bench, idle_s=0.02, max_s=1.0, loss_window_s=0.02):
    """Idle for ``idle_s``, command ``align``, run to TRACKING or FAULT; return metrics."""
    seq = bench.seq
    run = bench.align_run(idle_s, max_s, loss_window_s)
    out = dict(state=run['state'], fault_reason=run['fault_reason'], slot_m=float(
        bench.link.coupling.slot_position(run['t_stop'])), final_loss_db=None,
        peak_samples=None, time_to_first_light_s=run['time_to_first_light_s'],
        time_to_peak_s=run['time_to_peak_s'])
    if run['state'] == sq.TRACKING:
        out['peak_samples'] = int(run['peak_samples'])
        out['final_loss_db'] = float(np.mean(run['losses'])) if run['losses'] else None
    out['aligned'] = bool(seq.state == sq.TRACKING and out['final_loss_db'] is not None
                          and out['final_loss_db'] <= 0.05
                          and out['time_to_peak_s'] <= 0.5 and out['peak_samples'] <= 60)
    return out


def rise_time(t, p, lo, hi):
    """Return the 10-90 % rise time (s) of ``p`` between levels ``lo`` and ``hi`` (W)."""
    p10 = lo + 0.1 * (hi - lo)
    p90 = lo + 0.9 * (hi - lo)
    i10 = np.flatnonzero(p >= p10)
    i90 = np.flatnonzero(p >= p90)
    if i10.size == 0 or i90.size == 0:
        return None

    def cross(i, level):
        if i == 0:
            return t[0]
        f = (level - p[i - 1]) / (p[i] - p[i - 1])
        return t[i - 1] + f * (t[i] - t[i - 1])

    return float(cross(i90[0], p90) - cross(i10[0], p10))


def switch_cycles(bench, cycles=5, on_s=0.06, off_s=0.03, level_s=0.01):
    """
    Run ``cycles`` off/on switch cycles from TRACKING; return per-cycle metrics.

    :param on_s: time on (s) from the switch-on command to the switch-off command.
    :param off_s: time off (s).
    :param level_s: window (s) at the end of the on period for the on level and loss.
    """
    seq = bench.seq
    rises, losses, faults = [], [], []
    for i in range(cycles):
        ok, msg = seq.switch(False)
        if not ok:
            faults.append(msg)
            break
        t_off = bench.t
        p_off = []
        while bench.t < t_off + off_s - 1e-12:
            bench.step()
            p_off.append(bench.last[2])
        ok, msg = seq.switch(True)
        if not ok:
            faults.append(msg)
            break
        t_on = bench.t
        tt, pp, ll = [], [], []
        while bench.t < t_on + on_s - 1e-12:
            bench.step()
            tt.append(bench.last[0])
            pp.append(bench.last[2])
            ll.append(true_loss(bench))
        n_level = max(1, int(round(level_s / bench.period_s)))
        hi = float(np.mean(pp[-n_level:]))
        lo = float(np.mean(p_off[-n_level:])) if p_off else 0.0
        rises.append(rise_time(np.asarray(tt), np.asarray(pp), lo, hi))
        losses.append(float(np.mean(ll[-n_level:])))
        if seq.state != sq.TRACKING:
            faults.append('cycle %d ended in %s %s' % (i, seq.state, seq.fault_reason))
            break
    good = [r for r in rises if r is not None]
    out = dict(cycles=len(losses), switch_rise_time_s=max(good) if good else None,
               switch_rise_time_median_s=float(np.median(good)) if good else None,
               cycle_loss_db=losses, switch_faults=faults)
    if losses:
        n = max(1, min(10, len(losses) // 2))
        out['cycle_loss_first_db'] = float(np.mean(losses[:n]))
        out['cycle_loss_last_db'] = float(np.mean(losses[-n:]))
        out['cycle_loss_drift_db'] = out['cycle_loss_last_db'] - out['cycle_loss_first_db']
        out['cycle_loss_max_db'] = float(np.max(losses))
    return out


def track_bench(bench, duration_s):
    """Keep TRACKING for ``duration_s`` (s); return the loss statistics (dB)."""
    seq = bench.seq
    t_end = bench.t + duration_s
    losses = []
    while bench.t < t_end - 1e-12 and seq.state == sq.TRACKING:
        bench.step()
        losses.append(true_loss(bench))
    arr = np.asarray(losses)
    return dict(tracking_max_loss_db=float(arr.max()) if arr.size else None,
                tracking_mean_loss_db=float(arr.mean()) if arr.size else None,
                tracking_time_s=float(arr.size * bench.period_s),
                tracking_state=seq.state, tracking_fault=seq.fault_reason)


def run(name, seed=0, loop='composite', record=False, **kw):
    """
    Run scenario ``name`` (align, switch, track); return a dict of SI metrics.

    Keyword arguments: ``slot_m`` (m), ``cycles``, ``duration_s`` (s),
    ``drift_m_per_s`` (m/s), ``period_s`` (s), ``seq_params`` / ``optics_params``
    (mappings replacing the config files), ``setup`` (the loaded
    :class:`~fiber_align.simulation.simulate.Setup`), other keys of ``config/optics.yaml``.
    With ``record=True`` the result holds ``trace`` (dict of arrays) for plotting.
    """
    if name not in SCENARIOS:
        raise ValueError('unknown scenario %r (allowed: %s)' % (name, ', '.join(SCENARIOS)))
    kw = dict(kw)
    cycles = int(kw.pop('cycles', 5))
    duration_s = float(kw.pop('duration_s', 60.0))
    drift = float(kw.pop('drift_m_per_s', 1e-6))
    hold_s = float(kw.pop('hold_s', 0.1))
    if name == 'track':
        kw.setdefault('slot_m', 3e-6)
        kw['slot_drift_m_per_s'] = drift
    bench = build(seed=seed, loop=loop, record=record, **kw)
    out = {k: None for k in METRIC_KEYS}
    out.update(scenario=name, seed=seed, loop=getattr(bench.loop, 'name', str(loop)),
               control_rate_hz=1.0 / bench.period_s)
    out.update(align_bench(bench))
    if name == 'switch' and bench.seq.state == sq.TRACKING:
        bench.run_until(bench.t + hold_s)
        out.update(switch_cycles(bench, cycles=cycles))
    elif name == 'track' and bench.seq.state == sq.TRACKING:
        out.update(track_bench(bench, duration_s))
    out['end_state'] = bench.seq.state
    out['end_fault_reason'] = bench.seq.fault_reason
    out['simulated_s'] = bench.t
    if record:
        out['trace'] = bench.rec.arrays()
        out['events'] = [(t, s, m) for t, s, m in bench.seq.events]
    return out


def align_trials(n=20, seed=0, loop='ideal', **kw):
    """
    Align ``n`` times, slots spread over the reachable range, seeds ``seed..seed+n-1``.

    Slot ``i`` is drawn uniformly inside the i-th of ``n`` equal bins of the range, so
    the whole range is covered. Returns ``(list of per-trial dicts, summary dict)``.
    """
    sp = load_params(sq.CONFIG_FILE, sq.CONFIG_NODE)
    lo, hi = float(sp['range_min_m']), float(sp['range_max_m'])
    rng = np.random.default_rng(seed)
    edges = np.linspace(lo, hi, n + 1)
    trials = []
    for i in range(n):
        slot = float(rng.uniform(edges[i], edges[i + 1]))
        r = run('align', seed=seed + i, loop=loop, slot_m=slot, **kw)
        trials.append(r)
    ok = [r for r in trials if r['aligned']]
    bad = [r for r in trials if not r['aligned']]
    summary = dict(
        n=n, aligned=len(ok),
        silent_failures=sum(1 for r in bad if r['state'] != sq.FAULT),
        max_final_loss_db=max((r['final_loss_db'] for r in ok), default=None),
        max_time_to_peak_s=max((r['time_to_peak_s'] for r in ok), default=None),
        max_peak_samples=max((r['peak_samples'] for r in ok), default=None),
        failures=[(r['slot_m'], r['state'], r['fault_reason'], r['final_loss_db'])
                  for r in bad])
    return trials, summary


def run_cli(args):
    """
    Run ``fiber-align simulate --scenario align|switch|track``; return an exit code.

    Reads ``args.scenario``, ``args.seed``, ``args.json``, ``args.plot`` and, when present,
    ``args.loop``, ``args.cycles``, ``args.duration`` (s), ``args.slot`` (m),
    ``args.drift`` (m/s), ``args.rate`` (Hz); other attributes are ignored.
    """
    name = getattr(args, 'scenario', 'align')
    seed = int(getattr(args, 'seed', 0) or 0)
    kw = {}
    for attr, key in (('cycles', 'cycles'), ('duration', 'duration_s'), ('slot', 'slot_m'),
                      ('drift', 'drift_m_per_s')):
        v = getattr(args, attr, None)
        if v is not None:
            kw[key] = v
    rate = getattr(args, 'rate', None) or getattr(args, 'rate_hz', None)
    if rate:
        kw['period_s'] = 1.0 / float(rate)
    loop = getattr(args, 'loop', None) or 'composite'
    if loop not in ('composite', 'ideal'):
        loop = 'composite'
    plot = getattr(args, 'plot', None)
    res = run(name, seed=seed, loop=loop, record=bool(plot), **kw)
    if plot:
        plot_run(res, plot)
    clean = json_clean(res, drop=('trace',))
    if getattr(args, 'json', False):
        print(json.dumps(clean, indent=2, sort_keys=True))
    else:
        _print_human(clean, sys.stdout)
    return 0 if clean.get('end_state') == sq.TRACKING else 1


def _print_human(res, out):
    """Print the metrics of a run for people (dB, um, ms)."""
    def ms(v):
        return '-' if v is None else '%.1f ms' % (v * 1e3)

    def db(v):
        return '-' if v is None else '%.3f dB' % v

    print('scenario %s, seed %s, loop %s, %.0f Hz, slot %.2f um'
          % (res['scenario'], res['seed'], res['loop'], res['control_rate_hz'],
             res['slot_m'] * 1e6), file=out)
    print('  end state          %s %s' % (res['end_state'], res['end_fault_reason']),
          file=out)
    print('  time to first light %s' % ms(res['time_to_first_light_s']), file=out)
    print('  time to peak        %s (%s peak samples)'
          % (ms(res['time_to_peak_s']), res['peak_samples']), file=out)
    print('  final loss          %s' % db(res['final_loss_db']), file=out)
    if res.get('switch_rise_time_s') is not None:
        print('  switch rise 10-90%% %s max over %d cycles, loss drift %s'
              % (ms(res['switch_rise_time_s']), res['cycles'],
                 db(res.get('cycle_loss_drift_db'))), file=out)
    if res.get('tracking_max_loss_db') is not None:
        print('  tracking max loss   %s over %.1f s'
              % (db(res['tracking_max_loss_db']), res['tracking_time_s']), file=out)
