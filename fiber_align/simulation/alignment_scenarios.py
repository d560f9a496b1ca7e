# SPDX-License-Identifier: Apache-2.0
"""
Offline alignment scenarios of the one-axis machine: the sequencer as a loop's setpoint source.

One control period ``k`` (docs/CONTRACTS.md): the loop's measurement ``y_k`` (m) and the
detector reading ``P_k`` (W, from the true tip position at ``t_k``) go to
``Sequencer.update(t_k, y_k, P_k)``, whose setpoint ``r_k`` (m) drives the loop for one
period. The steps are those of :mod:`fiber_align.simulation.harness`. Scenarios
(``run(name, seed, **kw)`` returns a dict of SI metrics):

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

import numpy as np

from fiber_align.alignment import sequencer as sq
from fiber_align.config import load_params
from fiber_align.simulation import harness as hs
from fiber_align.simulation.alignment_bench import build
from fiber_align.simulation.harness import align_bench, rise_time  # noqa: F401 (the API)
from fiber_align.simulation.scenarios import MACHINE_SCENARIOS

SCENARIOS = MACHINE_SCENARIOS['one']
METRIC_KEYS = ('time_to_first_light_s', 'time_to_peak_s', 'final_loss_db', 'peak_samples',
               'switch_rise_time_s', 'tracking_max_loss_db')


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
        out.update(hs.switch_cycles(bench, cycles=cycles))
    elif name == 'track' and bench.seq.state == sq.TRACKING:
        out.update(hs.track_bench(bench, duration_s))
    hs.end(out, bench)
    if record:
        out['trace'] = bench.trace()
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


def run_cli(args, plot=None):
    """
    Run ``fiber-align simulate --scenario align|switch|track``; return an exit code.

    :param plot: ``plot(res, path)`` for ``--plot`` (the caller's figure; None: no figure).
    """
    return hs.run_cli(args, run, plot, ('cycles', 'duration', 'slot', 'drift'))
