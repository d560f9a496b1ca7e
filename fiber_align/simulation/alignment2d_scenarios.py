# SPDX-License-Identifier: Apache-2.0
"""
Offline two-axis scenarios: the 2-D sequencer (and its hill-climb baseline) on a rig.

The rig is two independent closed loops (:class:`Rig2D`: x and y, each its own plant,
composite controller, driver, sensor noise and seed, from the control core's config files),
stepped at the control rate in the order of docs/CONTRACTS.md. One period ``k``: both loops'
measurements ``(x_k, y_k)`` (m) and the detector reading ``P_k`` (W, of the true tip position
at ``t_k``) go to ``seq.update(t_k, x_k, y_k, P_k)``, whose setpoints drive the two loops for
one period. ``run(name, seed)`` runs scenario ``name`` with the sequencer and then, on the
same target and noise seeds, with the hill climb, and returns SI metrics (the baseline's
under ``baseline``):

``align2d``
    From IDLE, ``align`` with the target at a random point of the reachable square:
    ``time_to_first_light_s``, ``time_to_peak_s`` (command to TRACKING), ``final_loss_db``
    (true loss against the true maximum, mean over the first ``loss_window_s`` of TRACKING,
    dither included), ``peak_samples`` (readings in PEAKING, as the 1-D ``align``),
    ``search_samples``, ``samples`` (all readings from the command to TRACKING).
``track2d``
    Align, then track a target drifting at ``drift_m_per_s`` in a random direction and
    vibrating (``vibration_m`` at ``vibration_hz``, random direction) for ``duration_s``;
    loss statistics over the run after ``skip_s``.
``switch2d``
    Align, then ``cycles`` switch off/on cycles; the loss at the end of each on period.
"""

import json
import math
import sys

import numpy as np

from fiber_align.alignment import hillclimb2d as hc
from fiber_align.alignment.plots2d import plot_run2d
from fiber_align.simulation import alignment_bench as sc1
from fiber_align.alignment import sequencer2d as s2d
from fiber_align.jsonout import json_clean
from fiber_align.plant import optics2d as o2
from fiber_align.simulation.seeds2d import graph_period_s, random_target, run_seeds

SCENARIOS = ('align2d', 'track2d', 'switch2d')
METHODS = ('sequencer', 'hillclimb')
METRIC_KEYS = ('time_to_first_light_s', 'time_to_peak_s', 'final_loss_db', 'peak_samples',
               'search_samples', 'samples')
GOAL = dict(loss_db=0.05, time_s=1.0, samples=150)   # issue 14, align from IDLE


class Rig2D:
    """
    Two independent closed loops, x and y (SI: m, s).

    :param kind: ``composite`` (the control core's plant and composite controller) or
        ``ideal`` (the first-order stand-in of the 1-D scenarios, for fast tests).
    :param period_s: control period (s).
    :param seed: the x loop's noise seed; the y loop gets ``seed + 1``.
    """

    def __init__(self, kind='composite', period_s=1e-3, seed=0):
        """Build both loops."""
        self.kind = kind
        self.period_s = float(period_s)
        self.loops = (sc1.make_loop(kind, period_s, seed), sc1.make_loop(kind, period_s,
                                                                         seed + 1))
        self.reset(seed)

    def reset(self, seed):
        """Rest both loops; restart their noise with seeds ``seed`` and ``seed + 1``."""
        for i, lp in enumerate(self.loops):
            if hasattr(lp, 'plant'):
                lp.plant.seed = int(seed + i)
            else:
                lp.seed = int(seed + i)
            lp.reset()

    @property
    def position(self):
        """Return the true tip position ``(x, y)`` (m)."""
        return self.loops[0].position_m, self.loops[1].position_m

    @property
    def measured(self):
        """Return the sensor readings ``(x, y)`` (m)."""
        return self.loops[0].y_meas, self.loops[1].y_meas

    def step(self, rx_m, ry_m):
        """Run one control period of both loops for the setpoints (m)."""
        self.loops[0].step(rx_m)
        self.loops[1].step(ry_m)


class Bench2D(sc1.Stepping):
    """A sequencer, a 2-D optical link and a rig stepped together, one period a call."""

    FIELDS = ('t', 'x', 'y', 'mx', 'my', 'rx', 'ry', 'p', 'p_true', 'p_max', 'tx', 'ty')

    def __init__(self, rig, link, seq, record=False):
        """Combine the parts; time starts at 0 s."""
        self.rig, self.link, self.seq = rig, link, seq
        self.period_s = rig.period_s
        self.k = 0
        self.rows = {k: [] for k in self.FIELDS} if record else None
        self.states = []
        self.last = None

    def step(self):
        """Run one period; return ``(t, x, y, power reading)`` (s, m, m, W)."""
        t = self.t
        x, y = self.rig.position
        mx, my = self.rig.measured
        p = self.link.measure(t, x, y, self.period_s)
        rx, ry = self.seq.update(t, mx, my, p)
        if self.rows is not None:
            c = self.link.coupling
            tx, ty = c.target.position(t)
            for k, v in zip(self.FIELDS, (t, x, y, mx, my, rx, ry, p, c.power_w(t, x, y),
                                          c.max_power_w(), tx, ty)):
                self.rows[k].append(float(v))
            self.states.append(self.seq.state)
        self.last = (t, x, y, p)
        self.rig.step(rx, ry)
        self.k += 1
        return self.last

    def true_loss(self):
        """Return the true loss (dB) of the last period."""
        t, x, y, _ = self.last
        return float(self.link.loss_db(t, x, y))

    def trace(self):
        """Return the recorded run as a dict of arrays (SI) plus ``state`` and ``loss_db``."""
        out = {k: np.asarray(v) for k, v in self.rows.items()}
        out['state'] = np.asarray(self.states, dtype=object)
        out['loss_db'] = np.asarray(
            self.link.coupling.loss_db(out['t'], out['x'], out['y'])) if out['t'].size \
            else np.zeros(0)
        return out


def make_sequencer(method, **overrides):
    """Return a fresh ``sequencer`` (:class:`Sequencer2D`) or ``hillclimb`` baseline."""
    overrides.setdefault('period_s', graph_period_s())
    if method == 'sequencer':
        return s2d.Sequencer2D(**overrides)
    if method == 'hillclimb':
        return hc.HillClimb2D(**overrides)
    raise ValueError('unknown method %r (allowed: %s)' % (method, ', '.join(METHODS)))


def build(seed=0, method='sequencer', target=None, rig=None, record=False, seq_overrides=None,
          **optics_overrides):
    """
    Return a :class:`Bench2D` with the target at ``target`` (m; random if None).

    :param rig: a :class:`Rig2D` to reuse (reset with ``seed``), or a loop kind.
    :param optics_overrides: keys of ``optics.yaml`` and of the ``target`` of
        ``optics2d.yaml`` (e.g. ``fiber_broken=True``, ``drift_x_m_per_s``).
    """
    seq = make_sequencer(method, **(seq_overrides or {}))
    if target is None:
        target = random_target(seed, seq)
    ov = dict(optics_overrides)
    ov['position_x_m'], ov['position_y_m'] = float(target[0]), float(target[1])
    seeds = run_seeds(seed)
    if rig is None or isinstance(rig, str):
        rig = Rig2D(rig or 'composite', seq.period_s, seeds['plant_x'])
    rig.reset(seeds['plant_x'])
    ov.setdefault('sample_period_s', rig.period_s)
    link = o2.OpticalLink2D.from_params(None, None, seed=seeds['detector'], **ov)
    return Bench2D(rig, link, seq, record)


def align_bench(bench, idle_s=0.02, max_s=1.0, loss_window_s=0.02):
    """Idle ``idle_s``, command ``align``, run to TRACKING or FAULT; return metrics (SI)."""
    run = bench.align_run(idle_s, max_s, loss_window_s)
    tx, ty = bench.link.coupling.target.position(run['t_stop'])
    out = {k: None for k in METRIC_KEYS}
    out.update(state=run['state'], fault_reason=run['fault_reason'], target_x_m=tx,
               target_y_m=ty, iterations=run['iterations'],
               time_to_first_light_s=run['time_to_first_light_s'])
    if run['state'] == s2d.TRACKING:
        out['time_to_peak_s'] = run['time_to_peak_s']
        out['peak_samples'] = int(run['peak_samples'])
        out['search_samples'] = int(run['search_samples'])
        out['samples'] = int(round(out['time_to_peak_s'] / bench.period_s))
        out['final_loss_db'] = float(np.mean(run['losses'])) if run['losses'] else None
    out['aligned'] = bool(out['final_loss_db'] is not None
                          and out['final_loss_db'] <= GOAL['loss_db']
                          and out['time_to_peak_s'] <= GOAL['time_s']
                          and out['peak_samples'] <= GOAL['samples'])
    return out


def track_bench(bench, duration_s, skip_s=1.0, t_cmd=0.02):
    """Keep tracking for ``duration_s`` (s); loss statistics (dB) after ``t_cmd + skip_s``."""
    seq = bench.seq
    t_end = bench.t + duration_s
    losses = []
    while bench.t < t_end - 1e-12 and seq.state == s2d.TRACKING:
        bench.step()
        if bench.last[0] >= t_cmd + skip_s:
            losses.append(bench.true_loss())
    arr = np.asarray(losses)
    return dict(tracking_max_loss_db=float(arr.max()) if arr.size else None,
                tracking_mean_loss_db=float(arr.mean()) if arr.size else None,
                tracking_p99_loss_db=float(np.percentile(arr, 99)) if arr.size else None,
                tracking_time_s=float(arr.size * bench.period_s), tracking_state=seq.state,
                tracking_fault=seq.fault_reason)


def switch_cycles(bench, cycles=5, on_s=0.06, off_s=0.03, level_s=0.01):
    """
    Run ``cycles`` off/on cycles from TRACKING; the loss (dB) at the end of each on period.

    ``cycles_not_tracking`` counts the on periods that ended before TRACKING (still
    re-peaking); only a FAULT stops the cycles.
    """
    seq = bench.seq
    losses, faults, late = [], [], 0
    for i in range(cycles):
        ok, msg = seq.switch(False)
        if ok:
            bench.run_until(bench.t + off_s)
            ok, msg = seq.switch(True)
        if not ok:
            faults.append('cycle %d: %s' % (i, msg))
            break
        t_on = bench.t
        ll = []
        while bench.t < t_on + on_s - 1e-12:
            bench.step()
            if bench.t > t_on + on_s - level_s:
                ll.append(bench.true_loss())
        losses.append(float(np.mean(ll)))
        if seq.state != s2d.TRACKING:
            late += 1
        if seq.state == s2d.FAULT:
            faults.append('cycle %d: FAULT %s' % (i, seq.fault_reason))
            break
    out = dict(cycles=len(losses), cycle_loss_db=losses, switch_faults=faults,
               cycles_not_tracking=late)
    if losses:
        n = max(1, min(10, len(losses) // 2))
        arr = np.asarray(losses)
        out.update(cycle_loss_first_db=float(arr[:n].mean()),
                   cycle_loss_last_db=float(arr[-n:].mean()),
                   cycle_loss_max_db=float(arr.max()),
                   cycles_over_goal=int((arr > GOAL['loss_db']).sum()))
        out['cycle_loss_drift_db'] = out['cycle_loss_last_db'] - out['cycle_loss_first_db']
    return out


def run_method(name, method, seed=0, rig=None, record=False, target=None, **kw):
    """Run scenario ``name`` with one method; return a dict of SI metrics."""
    kw = dict(kw)
    cycles = int(kw.pop('cycles', 5))
    duration_s = float(kw.pop('duration_s', 60.0))
    drift = float(kw.pop('drift_m_per_s', 1e-6))
    vib = float(kw.pop('vibration_m', 0.2e-6))
    vib_hz = float(kw.pop('vibration_hz', 30.0))
    if name == 'track2d':
        rng = np.random.default_rng([seed, 60])
        ang, vang = rng.uniform(0.0, 2.0 * math.pi, 2)
        seq = make_sequencer('sequencer')
        # start so that the whole drift stays inside the square, centred on its middle
        mid = 0.5 * (seq.lo + seq.hi)
        u = np.array([math.cos(ang), math.sin(ang)])
        if target is None:
            target = tuple(mid - u * drift * 0.5 * (duration_s + 0.5))
        kw.update(drift_x_m_per_s=drift * u[0], drift_y_m_per_s=drift * u[1],
                  vibration_amplitude_m=vib, vibration_frequency_hz=vib_hz,
                  vibration_angle_rad=vang)
    bench = build(seed=seed, method=method, target=target, rig=rig, record=record, **kw)
    out = align_bench(bench)
    if name == 'switch2d' and bench.seq.state == s2d.TRACKING:
        bench.run_until(bench.t + 0.1)
        out.update(switch_cycles(bench, cycles=cycles))
    elif name == 'track2d' and bench.seq.state == s2d.TRACKING:
        out.update(track_bench(bench, duration_s))
        out.update(drift_m_per_s=drift, vibration_m=vib, vibration_hz=vib_hz)
    out.update(method=method, end_state=bench.seq.state,
               end_fault_reason=bench.seq.fault_reason, simulated_s=bench.t)
    if record:
        out['trace'] = bench.trace()
    return out


def run(name, seed=0, loop='composite', record=False, rig=None, **kw):
    """
    Run scenario ``name`` (align2d, track2d, switch2d) with the sequencer and the baseline.

    Returns the sequencer's metrics with the hill climb's under ``baseline`` and the ratios
    ``samples_ratio`` / ``time_ratio`` (hill climb / sequencer, peak samples and time to
    peak). Keyword arguments: ``target`` ``(x, y)`` (m), ``period_s`` (s; default the
    graph's 1 / ``rate_hz``), ``cycles``, ``duration_s`` (s),
    ``drift_m_per_s`` (m/s), ``vibration_m`` (m), ``vibration_hz`` (Hz), keys of the
    optics files.
    """
    if name not in SCENARIOS:
        raise ValueError('unknown scenario %r (allowed: %s)' % (name, ', '.join(SCENARIOS)))
    period_s = kw.pop('period_s', None)
    if period_s is not None:
        kw['seq_overrides'] = dict(period_s=float(period_s))
    rig = rig or Rig2D(loop, period_s or graph_period_s(), 2 * seed)
    out = run_method(name, 'sequencer', seed, rig, record, **kw)
    base = run_method(name, 'hillclimb', seed, rig, record, **kw)
    out.update(scenario=name, seed=seed, loop=loop, control_rate_hz=1.0 / rig.period_s,
               baseline=base)
    for key, k in (('samples_ratio', 'peak_samples'), ('time_ratio', 'time_to_peak_s')):
        a, b = out.get(k), base.get(k)
        out[key] = (b / a) if a and b is not None else None
    return out


def run_cli(args):
    """
    Run ``fiber-align simulate --scenario align2d|track2d|switch2d``; return an exit code.

    Reads ``args.scenario``, ``args.seed``, ``args.json``, ``args.plot`` and, when present,
    ``args.loop``, ``args.cycles``, ``args.duration`` (s), ``args.drift`` (m/s),
    ``args.rate`` (Hz), ``args.target`` ((x, y) in m). Exit code 0 when the sequencer ends
    TRACKING.
    """
    name = getattr(args, 'scenario', 'align2d')
    seed = int(getattr(args, 'seed', 0) or 0)
    kw = {}
    for attr, key in (('cycles', 'cycles'), ('duration', 'duration_s'),
                      ('drift', 'drift_m_per_s'), ('target', 'target')):
        v = getattr(args, attr, None)
        if v is not None:
            kw[key] = v
    rate = getattr(args, 'rate', None)
    if rate:
        kw['period_s'] = 1.0 / float(rate)
    loop = getattr(args, 'loop', None) or 'composite'
    plot = getattr(args, 'plot', None)
    res = run(name, seed=seed, loop=loop, record=bool(plot), **kw)
    if plot:
        plot_run2d(res, plot)
    clean = json_clean(res, drop=('trace',))
    if getattr(args, 'json', False):
        print(json.dumps(clean, indent=2, sort_keys=True))
    else:
        _print_human(clean, sys.stdout)
    return 0 if clean.get('end_state') == s2d.TRACKING else 1


def _print_human(res, out):
    """Print both methods' metrics for people (dB, um, ms)."""
    def f(v, scale=1.0, fmt='%.1f'):
        return '-' if v is None else fmt % (v * scale)

    print('scenario %s, seed %s, loop %s, %.0f Hz, target (%.2f, %.2f) um'
          % (res['scenario'], res['seed'], res['loop'], res['control_rate_hz'],
             res['target_x_m'] * 1e6, res['target_y_m'] * 1e6), file=out)
    for label, r in (('sequencer', res), ('hill climb', res['baseline'])):
        print('  %-10s %s %s: loss %s dB, time to peak %s ms, peak samples %s, all samples '
              '%s' % (label, r['end_state'], r['end_fault_reason'],
                      f(r['final_loss_db'], fmt='%.4f'), f(r['time_to_peak_s'], 1e3),
                      f(r['peak_samples'], fmt='%d'), f(r['samples'], fmt='%d')), file=out)
        if r.get('tracking_max_loss_db') is not None:
            print('             tracking: max loss %.4f dB, mean %.4f dB over %.1f s'
                  % (r['tracking_max_loss_db'], r['tracking_mean_loss_db'],
                     r['tracking_time_s']), file=out)
        if r.get('cycle_loss_max_db') is not None:
            print('             switch: %d cycles, loss max %.4f dB, drift %+.4f dB'
                  % (r['cycles'], r['cycle_loss_max_db'], r['cycle_loss_drift_db']), file=out)
