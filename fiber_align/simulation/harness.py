# SPDX-License-Identifier: Apache-2.0
"""
The one offline scenario harness: any machine's sequencer on its closed loops and its link.

A machine is an axis list (each axis one closed loop of
:mod:`fiber_align.simulation.alignment_bench`: plant, compensator, feedback, driver), its
optical link and its sequencer. One control period ``k`` (docs/CONTRACTS.md), the same for
every machine: the loops' measurements ``m_k`` (m) and the detector reading ``P_k`` (W, of
the true positions at ``t_k``) go to the sequencer's ``update``, whose setpoints ``r_k`` (m)
drive the loops for one period. :class:`Bench` steps a machine; a machine's bench is a
subclass that names its axes in the trace (data) and says how its sequencer takes the
measurements (``JOINT``). On it, the scenario steps written once: :func:`align_bench`,
:func:`switch_cycles`, :func:`track_bench`; :func:`run_cli` prints any machine's result
(JSON or for people). The machines: :mod:`~fiber_align.simulation.alignment_scenarios`
(one axis), :mod:`~fiber_align.simulation.alignment2d_scenarios` (the x-y rig),
:mod:`~fiber_align.simulation.station_scenarios` (the coupled station, four axes).
SI units throughout.
"""

import json
import sys

import numpy as np

from fiber_align.alignment.states import FAULT, PEAKING, TRACKING
from fiber_align.jsonout import json_clean
from fiber_align.plant import optics as op

#: What :meth:`Bench.align_run` reports of the sequencer when the run stops.
SNAPSHOT = ('state', 'fault_reason', 'peak_samples', 'search_samples', 'iterations')
#: The keys of :func:`align_bench` (``None`` where a run did not reach them).
ALIGN_KEYS = ('time_to_first_light_s', 'time_to_peak_s', 'final_loss_db', 'peak_samples',
              'search_samples', 'samples')


class Rig:
    """
    Independent closed loops, one per axis (SI: m, s); ``seed`` seeds loop ``i`` with ``seed + i``.

    :param loops: the loops (each ``position_m``, ``y_meas``, ``step(r)``, ``reset()``).
    :param period_s: control period (s).
    :param seed: None: the loops keep their seeds and are only reset.
    """

    def __init__(self, loops, period_s, seed=None):
        """Hold the loops; reset them (with seeds ``seed + i`` unless ``seed`` is None)."""
        self.loops = tuple(loops)
        self.period_s = float(period_s)
        self.reset(seed)

    def reset(self, seed=None):
        """Rest every loop; restart loop ``i``'s noise with seed ``seed + i``."""
        for i, lp in enumerate(self.loops):
            if seed is not None:
                if hasattr(lp, 'plant'):
                    lp.plant.seed = int(seed + i)
                else:
                    lp.seed = int(seed + i)
            lp.reset()

    @property
    def position(self):
        """Return the true positions (m), one per axis."""
        return tuple(lp.position_m for lp in self.loops)

    @property
    def measured(self):
        """Return the sensor readings (m), one per axis."""
        return tuple(lp.y_meas for lp in self.loops)

    def step(self, r):
        """Run one control period of every loop for the setpoints ``r`` (m)."""
        for lp, v in zip(self.loops, r):
            lp.step(v)


class Bench:
    """
    A machine stepped one control period a call: its rig, its link and its sequencer.

    Per machine (class data): ``POSITION``, ``MEASURED``, ``SETPOINT``, ``TARGET``: the
    trace's column names per axis (true position, sensor reading, setpoint, where the
    link couples best); ``JOINT``: the sequencer takes the readings as one tuple
    (``update(t, m, p, active)``) instead of one argument per axis; ``GOAL``: the
    alignment goal of :func:`align_bench` (``loss_db``, ``time_s``, ``samples``; None:
    no limit); ``ALIGN_MAX_S``: the longest alignment (s). The link is a
    :class:`fiber_align.plant.link.Link` unless the machine overrides :meth:`sense`,
    :meth:`truth` and :meth:`loss`.
    """

    POSITION = MEASURED = SETPOINT = TARGET = ()
    POWERS = ('p',)             # the trace's readings: ``sense`` returns one, or a tuple
    JOINT = False
    GOAL = dict(loss_db=0.05, time_s=None, samples=None)
    ALIGN_MAX_S = 1.0
    #: how :func:`align_bench` reports the best point: one key per axis, or one key (a list)
    WHERE = 'target_m'
    FIELDS, TRUTH = ('t', 'p'), ('p_true', 'p_max')     # the trace's: seen and set; truth

    #: the machine's rig, ``RIG(kind, period_s, seed)``, and link, ``LINK.from_params(...)``
    RIG = LINK = None
    #: what a driver that holds its output drives its axis to (m): its safe output
    SAFE_M = 0.0

    @classmethod
    def assemble(cls, seq, rig, seeds, record=False, **optics_overrides):
        """
        Return a bench of this machine: ``rig`` (reused, or a loop kind) reset, a fresh link.

        :param seeds: ``(plant, detector)``: the rig's first noise seed, the detector's.
        :param optics_overrides: keys of the machine's link (``LINK.from_params``).
        """
        if rig is None or isinstance(rig, str):
            rig = cls.RIG(rig or 'composite', seq.period_s, seeds[0])
        rig.reset(seeds[0])
        optics_overrides.setdefault('sample_period_s', rig.period_s)
        return cls(rig, cls.LINK.from_params(None, None, seed=seeds[1], **optics_overrides),
                   seq, record)

    def __init_subclass__(cls, **kw):
        """Derive a machine's ``FIELDS`` and ``TRUTH`` from its column names."""
        super().__init_subclass__(**kw)
        cls.FIELDS = ('t',) + cls.MEASURED + cls.SETPOINT + cls.POWERS
        cls.TRUTH = cls.POSITION + ('p_true', 'p_max') + cls.TARGET

    def __init__(self, rig, link, seq, record=False):
        """Combine the parts; time starts at 0 s; ``record``: keep :meth:`trace`'s rows."""
        self.rig, self.link, self.seq = rig, link, seq
        self.period_s = rig.period_s
        self.k = 0
        self.last = None
        self.rows = {k: [] for k in self.FIELDS + self.TRUTH} if record else None
        self.states = []
        #: what the drivers report to the sequencer (None, a bool or one bool per axis)
        self.driver_active = None

    @property
    def t(self):
        """Return the time of the next period (s)."""
        return self.k * self.period_s

    def sense(self, t, pos):
        """Return the detector reading (W) with the axes at ``pos`` (m) at ``t`` (s)."""
        return self.link.detector.measure(float(self.link.coupling.power_at(t, pos)),
                                          self.period_s)

    def truth(self, t, pos):
        """Return the true power, the peak power (W) and the best point (m) at ``t``."""
        c = self.link.coupling
        return c.power_at(t, pos), c.max_power_w(), c.peak(t)

    def loss(self, t, pos):
        """Return the true loss in dB with the axes at ``pos`` (m), at ``t`` (s)."""
        return self.link.coupling.loss_at(t, pos)

    def command(self, t, m, p):
        """Return the sequencer's setpoints (m, one per axis) for readings ``m``, ``p``."""
        if self.JOINT:
            return self.seq.update(t, m, p, self.driver_active)
        r = self.seq.update(t, *m, p, self.driver_active)
        return tuple(r) if len(m) > 1 else (r,)

    def step(self):
        """Run one period; return ``(t, positions, reading)`` (s, m, W)."""
        t = self.t
        pos = self.rig.position
        m = self.rig.measured
        p = self.sense(t, pos)
        r = self.command(t, m, p)
        if self.rows is not None:
            p_true, p_max, target = self.truth(t, pos)
            for k, v in zip(self.FIELDS + self.TRUTH,
                            (t, *m, *r, *np.atleast_1d(p), *pos, p_true, p_max, *target)):
                self.rows[k].append(float(v))
            self.states.append(self.seq.state)
        self.last = (t, pos, p)
        self.rig.step(self.driven(r))
        self.k += 1
        return self.last

    def driven(self, r):
        """Return what the drivers make of the setpoints ``r`` (m): held axes go to SAFE_M."""
        up = self.driver_active
        ups = (up,) * len(r) if up is None or isinstance(up, bool) else up
        return tuple(self.SAFE_M if u is False else v for v, u in zip(r, ups))

    def true_loss(self):
        """Return the true loss (dB) of the last period."""
        t, pos, _ = self.last
        return float(self.loss(t, pos))

    def trace(self):
        """Return the recorded run (``record``): arrays (SI), ``state`` and ``loss_db``."""
        out = {k: np.asarray(v, dtype=float) for k, v in self.rows.items()}
        out['state'] = np.asarray(self.states, dtype=object)
        out['loss_db'] = op.loss_db(np.maximum(out['p_true'], 1e-30),
                                    np.maximum(out['p_max'], 1e-30))
        return out

    def where(self, t):
        """Return what :func:`align_bench` reports of the link at ``t`` (s): the best point."""
        pk = self.truth(t, self.rig.position)[2]
        if isinstance(self.WHERE, str):
            return {self.WHERE: [float(v) for v in pk]}
        return {k: float(v) for k, v in zip(self.WHERE, pk)}

    def run_until(self, t_end, stop=None):
        """Step until ``t_end`` (s) or until ``stop(bench)`` is true; return the time (s)."""
        while self.t < t_end - 1e-12:
            self.step()
            if stop is not None and stop(self):
                break
        return self.t

    def align_run(self, idle_s, max_s, loss_window_s):
        """
        Idle ``idle_s``, command ``align``, run to TRACKING or FAULT, then the loss window.

        :param max_s: the longest run after the command (s).
        :param loss_window_s: time in TRACKING over which the true loss is taken (s).
        :returns: dict: ``t_cmd`` (s), ``time_to_first_light_s`` (command to the first
            update in PEAKING, s), ``time_to_peak_s`` (command to the update that entered
            TRACKING, s; ``None`` if it did not), ``losses`` (dB, one per period of the
            window), and as they were when the run stopped (before the window): ``t_stop``
            (s) and the sequencer's ``state``, ``fault_reason``, ``peak_samples``,
            ``search_samples``, ``iterations`` (``None`` where it has none).
        """
        seq = self.seq
        self.run_until(idle_s)
        t_cmd = self.t
        seq.align()
        first = [None]

        def stop(b):
            if first[0] is None and seq.state == PEAKING:
                first[0] = b.t - b.period_s
            return seq.state in (TRACKING, FAULT)

        self.run_until(t_cmd + max_s, stop)
        out = {k: getattr(seq, k, None) for k in SNAPSHOT}
        out.update(t_cmd=t_cmd, t_stop=self.t, time_to_peak_s=None, losses=[],
                   time_to_first_light_s=None if first[0] is None else first[0] - t_cmd)
        if seq.state == TRACKING:
            out['time_to_peak_s'] = self.t - self.period_s - t_cmd
            t_end = self.t + loss_window_s
            while self.t < t_end - 1e-12 and seq.state == TRACKING:
                self.step()
                out['losses'].append(self.true_loss())
        return out


def align_bench(bench, idle_s=0.02, max_s=None, loss_window_s=0.02):
    """
    Idle ``idle_s``, command ``align``, run to TRACKING or FAULT; return metrics (SI).

    ``aligned``: still TRACKING after the loss window, the mean true loss over it within the
    machine's ``GOAL`` and, where it sets them, the time to peak and the peak samples.
    """
    seq = bench.seq
    run = bench.align_run(idle_s, bench.ALIGN_MAX_S if max_s is None else max_s,
                          loss_window_s)
    out = {k: None for k in ALIGN_KEYS}
    out.update(state=run['state'], fault_reason=run['fault_reason'],
               iterations=run['iterations'], method=getattr(seq, 'method', None),
               time_to_first_light_s=run['time_to_first_light_s'], **bench.where(run['t_stop']))
    if run['state'] == TRACKING:
        out['time_to_peak_s'] = run['time_to_peak_s']
        out['peak_samples'] = int(run['peak_samples'])
        out['search_samples'] = None if run['search_samples'] is None \
            else int(run['search_samples'])
        out['samples'] = int(round(run['time_to_peak_s'] / bench.period_s))
        out['final_loss_db'] = float(np.mean(run['losses'])) if run['losses'] else None
    g = bench.GOAL
    out['aligned'] = bool(seq.state == TRACKING and out['final_loss_db'] is not None
                          and out['final_loss_db'] <= g['loss_db']
                          and (g['time_s'] is None or out['time_to_peak_s'] <= g['time_s'])
                          and (g['samples'] is None or out['peak_samples'] <= g['samples']))
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
    Run ``cycles`` off/on switch cycles from TRACKING; return per-cycle metrics (SI, dB).

    Per cycle: the 10-90 % rise of the measured power after the switch-on and the mean true
    loss over the last ``level_s`` (s) of the on period (``on_s``, s; off ``off_s``, s).
    ``cycles_not_tracking`` counts the on periods that ended before TRACKING (still
    re-peaking); only a refused command or a FAULT stops the cycles.
    """
    seq = bench.seq
    rises, losses, faults, late = [], [], [], 0
    n_level = max(1, int(round(level_s / bench.period_s)))
    for i in range(cycles):
        ok, msg = seq.switch(False)
        p_off = []
        if ok:
            t_off = bench.t
            while bench.t < t_off + off_s - 1e-12:
                p_off.append(bench.step()[2])
            ok, msg = seq.switch(True)
        if not ok:
            faults.append('cycle %d: %s' % (i, msg))
            break
        t_on = bench.t
        tt, pp, ll = [], [], []
        while bench.t < t_on + on_s - 1e-12:
            t, _, p = bench.step()
            tt.append(t)
            pp.append(p)
            ll.append(bench.true_loss())
        hi = float(np.mean(pp[-n_level:]))
        lo = float(np.mean(p_off[-n_level:])) if p_off else 0.0
        rises.append(rise_time(np.asarray(tt), np.asarray(pp), lo, hi))
        losses.append(float(np.mean(ll[-n_level:])))
        if seq.state != TRACKING:
            late += 1
        if seq.state == FAULT:
            faults.append('cycle %d: FAULT %s' % (i, seq.fault_reason))
            break
    good = [r for r in rises if r is not None]
    out = dict(cycles=len(losses), switch_rise_time_s=max(good) if good else None,
               switch_rise_time_median_s=float(np.median(good)) if good else None,
               cycle_loss_db=losses, switch_faults=faults, cycles_not_tracking=late)
    if losses:
        n = max(1, min(10, len(losses) // 2))
        arr = np.asarray(losses)
        out.update(cycle_loss_first_db=float(arr[:n].mean()),
                   cycle_loss_last_db=float(arr[-n:].mean()),
                   cycle_loss_max_db=float(arr.max()),
                   cycles_over_goal=int((arr > bench.GOAL['loss_db']).sum()))
        out['cycle_loss_drift_db'] = out['cycle_loss_last_db'] - out['cycle_loss_first_db']
    return out


def track_bench(bench, duration_s, skip_until_s=0.0):
    """Keep TRACKING for ``duration_s`` (s); loss statistics (dB) from ``skip_until_s`` (s)."""
    seq = bench.seq
    t_end = bench.t + duration_s
    losses = []
    while bench.t < t_end - 1e-12 and seq.state == TRACKING:
        bench.step()
        if bench.last[0] >= skip_until_s:
            losses.append(bench.true_loss())
    arr = np.asarray(losses)
    return dict(tracking_max_loss_db=float(arr.max()) if arr.size else None,
                tracking_mean_loss_db=float(arr.mean()) if arr.size else None,
                tracking_p99_loss_db=float(np.percentile(arr, 99)) if arr.size else None,
                tracking_time_s=float(arr.size * bench.period_s), tracking_state=seq.state,
                tracking_fault=seq.fault_reason)


def ratio(num, den):
    """Return ``num / den``, or None when either is missing (or ``den`` is 0)."""
    return num / den if num is not None and den else None


def end(out, bench):
    """Add the sequencer's end state, fault and the simulated time (s) to ``out``."""
    out.update(end_state=bench.seq.state, end_fault_reason=bench.seq.fault_reason,
               simulated_s=bench.t)
    return out


#: ``fiber-align simulate`` options and the ``run`` keyword each sets (SI).
CLI_OPTIONS = (('cycles', 'cycles'), ('duration', 'duration_s'), ('slot', 'slot_m'),
               ('drift', 'drift_m_per_s'), ('target', 'target'))


def run_cli(args, run, plot=None, options=()):
    """
    Run ``fiber-align simulate --scenario S`` with a machine's ``run``; return an exit code.

    Reads ``args.scenario, seed, json, rate`` (Hz), ``loop``, ``plot`` (with ``plot(res,
    path)``), the ``options`` of :data:`CLI_OPTIONS` the machine takes; ``args.on_result``
    (the catalogue's hook) gets the result. Exit code 0 when the sequencer ends TRACKING.
    """
    kw = {key: getattr(args, attr) for attr, key in CLI_OPTIONS
          if attr in options and getattr(args, attr, None) is not None}
    rate = getattr(args, 'rate', None)
    if rate:
        kw['period_s'] = 1.0 / float(rate)
    loop = getattr(args, 'loop', None)
    path = getattr(args, 'plot', None) if plot is not None else None
    res = run(args.scenario, seed=int(getattr(args, 'seed', 0) or 0),
              loop=loop if loop in ('composite', 'ideal') else 'composite',
              record=bool(path), **kw)
    if path:
        plot(res, path)
    clean = json_clean(res, drop=('trace',))
    getattr(args, 'on_result', lambda result: None)(clean)
    if getattr(args, 'json', False):
        print(json.dumps(clean, indent=2, sort_keys=True))
    else:
        print_human(clean, sys.stdout)
    return 0 if clean.get('end_state') == TRACKING else 1


def print_human(res, out):
    """Print a run's figures for people (dB, um, ms): the method, its baseline, the extras."""
    def f(v, scale=1.0, fmt='%.1f'):
        return '-' if v is None else fmt % (v * scale)

    where = res.get('facets_m') or [res[k] for k in ('slot_m', 'target_x_m', 'target_y_m')
                                    if k in res]
    print('scenario %s, seed %s, loop %s, %.0f Hz, target (%s) um'
          % (res['scenario'], res['seed'], res['loop'], res['control_rate_hz'],
             ', '.join(f(v, 1e6, '%.2f') for v in where)), file=out)
    rows = [(res.get('method') or 'sequencer', res)]
    if res.get('baseline'):
        rows.append((res['baseline'].get('method') or 'baseline', res['baseline']))
    for label, r in rows:
        print('  %-10s %s %s: loss %s dB, first light %s ms, time to peak %s ms, peak '
              'samples %s, all samples %s'
              % (label, r.get('end_state', r['state']), r['fault_reason'],
                 f(r['final_loss_db'], fmt='%.4f'), f(r['time_to_first_light_s'], 1e3),
                 f(r['time_to_peak_s'], 1e3), f(r['peak_samples'], fmt='%d'),
                 f(r['samples'], fmt='%d')), file=out)
        if r.get('tracking_max_loss_db') is not None:
            print('             tracking: max loss %.4f dB, mean %.4f dB over %.1f s'
                  % (r['tracking_max_loss_db'], r['tracking_mean_loss_db'],
                     r['tracking_time_s']), file=out)
        if r.get('cycle_loss_max_db') is not None:
            print('             switch: %d cycles, rise 10-90 %% %s ms max, loss max %.4f dB, '
                  'drift %+.4f dB' % (r['cycles'], f(r['switch_rise_time_s'], 1e3),
                                      r['cycle_loss_max_db'], r['cycle_loss_drift_db']),
                  file=out)
    if res.get('max_loss_db') is not None:
        print('  cure: tracked max loss %.4f dB, final %.4f dB; untracked max %.4f dB, final '
              '%.4f dB' % (res['max_loss_db'], res['final_loss_db'],
                           res['untracked_max_loss_db'], res['untracked_final_loss_db']),
              file=out)
