# SPDX-License-Identifier: Apache-2.0
"""
Control benchmarks: us per step of the parts, fuzzy vs scikit-fuzzy, simulation speed.

The machine may be shared: every figure is the best of several repetitions, timed by
the process's CPU time (``time.process_time``), which other processes do not inflate;
the simulation rows also give the best wall time. Goal (issue 5): the offline
simulation at 10 kHz at least 20x faster than real time.
"""

import time

import numpy as np

from fiber_align.config import load_params
from fiber_align.control.fuzzy import FuzzyInference
from fiber_align.control.fuzzy_surface import FuzzySurface
from fiber_align.control.fuzzy_pid import FuzzyPid, make_pid, PlainPid
from fiber_align.hysteresis.playbank import PlayBank
from fiber_align.hysteresis.truth import make_hysteresis
from fiber_align.simulation.simulate import load_setup, run

REPEATS = 5


def _per_call_us(fn, n, repeats=REPEATS):
    """Return the best mean CPU time (us) of ``fn()`` over n calls."""
    best = float('inf')
    for _ in range(repeats):
        t = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, time.process_time() - t)
    return best / n * 1e6


def _sim_speed(controller, setup, rate_hz=10000.0, duration_s=1.0, repeats=REPEATS):
    """
    Return ``(cpu_s, wall_s)``: the best times of a sine run.

    Building the run's objects from the loaded configuration ``setup`` is included;
    loading it (files, design mode, fuzzy surface: once per program) is not.
    """
    cpu, wall = float('inf'), float('inf')
    for _ in range(repeats):
        t0, w0 = time.process_time(), time.perf_counter()
        run('sine', controller, rate_hz=rate_hz, duration_s=duration_s, setup=setup)
        cpu = min(cpu, time.process_time() - t0)
        wall = min(wall, time.perf_counter() - w0)
    return cpu, wall


def _skfuzzy_us(fis, n=50):
    """Return us per ControlSystemSimulation.compute() on the same rule base, or None."""
    try:
        import skfuzzy as fuzz
        from skfuzzy import control as ctrl
    except ImportError:
        return None
    labels = ('NB', 'NM', 'NS', 'ZO', 'PS', 'PM', 'PB')

    def var(cls, name, lo, hi):
        """Return a variable with seven evenly spaced triangles."""
        v = cls(np.linspace(lo, hi, 1001), name)
        h = (hi - lo) / 6.0
        for i, lab in enumerate(labels):
            p = lo + i * h
            v[lab] = fuzz.trimf(v.universe, [p - h, p, p + h])
        return v
    e = var(ctrl.Antecedent, 'e', *fis.e_domain)
    ec = var(ctrl.Antecedent, 'ec', *fis.ec_domain)
    names = ('dkp', 'dki', 'dkd')
    outs = [var(ctrl.Consequent, n, *d) for n, d in zip(names, fis.out_domains)]
    rules = []
    for i in range(7):
        for j in range(7):
            rules.append(ctrl.Rule(e[labels[i]] & ec[labels[j]],
                                   tuple(o[labels[fis.rules[k][i][j]]]
                                         for k, o in enumerate(outs))))
    sim = ctrl.ControlSystemSimulation(ctrl.ControlSystem(rules))

    it = _inputs(fis)

    def one():
        """Run one inference on the next input (fresh inputs defeat its result cache)."""
        a, b = next(it)
        sim.input['e'] = a
        sim.input['ec'] = b
        sim.compute()
    return _per_call_us(one, n)


def _inputs(fis, n=997):
    """Return an endless iterator over n seeded random (E, EC) points inside the domains."""
    import itertools
    rng = np.random.default_rng(0)
    e = rng.uniform(*fis.e_domain, n).tolist()
    ec = rng.uniform(*fis.ec_domain, n).tolist()
    return itertools.cycle(list(zip(e, ec)))


def main():
    """Print the Markdown table."""
    ctl = load_params('controller.yaml', 'fuzzy_pid_controller')
    fis = FuzzyInference.from_params(ctl['fuzzy'])
    q = int(ctl['fuzzy'].get('surface_intervals', 48)) or 48
    t = time.perf_counter()
    surf = FuzzySurface(fis, q)
    build_s = time.perf_counter() - t
    rows = []
    it = _inputs(fis)
    us_fuzzy = _per_call_us(lambda: fis.evaluate(*next(it)), 20000)
    rows.append(('fuzzy inference, exact closed form, one evaluation (3 outputs)',
                 '%.2f us' % us_fuzzy))
    us_surf = _per_call_us(lambda: surf.evaluate(*next(it)), 20000)
    rows.append(('fuzzy inference, surface q = %d (error <= 1e-3 of span, proven)' % q,
                 '%.2f us (built in %.2f s)' % (us_surf, build_s)))
    us_sk = _skfuzzy_us(fis)
    if us_sk is not None:
        rows.append(('scikit-fuzzy ControlSystemSimulation.compute(), same rules',
                     '%.0f us (%.0fx the exact closed form, %.0fx the surface)'
                     % (us_sk, us_sk / us_fuzzy, us_sk / us_surf)))
    law = make_hysteresis('dense-pi')
    bank = PlayBank(law.thresholds, law.weights)
    u = (40.0 + 40.0 * np.sin(np.linspace(0.0, 6.0, 5000))).tolist()

    def run_law(step):
        """Step through the drive."""
        for x in u:
            step(x)
    us_bank = _per_call_us(lambda: run_law(bank.step), 1) / len(u)
    rows.append(('plant hysteresis (50 play operators), one step: PlayBank.step (lazy '
                 'prefix; PIModel.step is the same bank)', '%.2f us' % us_bank))
    pid = PlainPid(make_pid(ctl, 10000.0))
    fz = FuzzyPid.from_params(ctl, 10000.0)
    rows.append(('pid step', '%.2f us' % _per_call_us(lambda: pid.step(1e-6, 0.0), 20000)))
    us_fz = _per_call_us(lambda: fz.step(1e-6, 0.0), 20000)
    rows.append(('fuzzy PID step (surface)', '%.2f us' % us_fz))
    setup = load_setup()
    for c in ('pid', 'fuzzy', 'composite'):
        cpu, wall = _sim_speed(c, setup)
        rows.append(('offline simulation, %s, 10 kHz, 1 s sine' % c,
                     '%.1fx real time by CPU time (%.1f us/period), %.1fx by wall time'
                     % (1.0 / cpu, cpu / 1e4 * 1e6, 1.0 / wall)))
    print('| measurement | value |')
    print('|---|---|')
    for k, v in rows:
        print('| %s | %s |' % (k, v))


if __name__ == '__main__':
    main()
