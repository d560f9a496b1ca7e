# SPDX-License-Identifier: Apache-2.0
"""Control benchmarks: us per controller step, fuzzy vs scikit-fuzzy, simulation speed."""

import time

import numpy as np

from fiber_align.config import load_params
from fiber_align.control.fuzzy import FuzzyInference
from fiber_align.control.fuzzy_pid import FuzzyPid, make_pid, PlainPid
from fiber_align.control.simulate import run


def _per_call_us(fn, n):
    """Return the mean wall time (us) of ``fn()`` over n calls."""
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t) / n * 1e6


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

    def one():
        """Run one inference."""
        sim.input['e'] = 1.3
        sim.input['ec'] = -4.2
        sim.compute()
    return _per_call_us(one, n)


def main():
    """Print the Markdown table."""
    ctl = load_params('controller.yaml', 'fuzzy_pid_controller')
    fis = FuzzyInference.from_params(ctl['fuzzy'])
    rows = []
    us_fuzzy = _per_call_us(lambda: fis.evaluate(1.3, -4.2), 20000)
    rows.append(('fuzzy inference, one evaluation (3 outputs)', '%.2f us' % us_fuzzy))
    us_sk = _skfuzzy_us(fis)
    if us_sk is not None:
        rows.append(('scikit-fuzzy ControlSystemSimulation.compute(), same rules',
                     '%.0f us (%.0fx slower)' % (us_sk, us_sk / us_fuzzy)))
    pid = PlainPid(make_pid(ctl, 10000.0))
    fz = FuzzyPid.from_params(ctl, 10000.0)
    rows.append(('pid step', '%.2f us' % _per_call_us(lambda: pid.step(1e-6, 0.0), 20000)))
    us_fz = _per_call_us(lambda: fz.step(1e-6, 0.0), 20000)
    rows.append(('fuzzy PID step', '%.2f us' % us_fz))
    run('step', 'composite', rate_hz=10000.0, duration_s=0.01)  # identify once, cached
    for c in ('pid', 'fuzzy', 'composite'):
        t = time.perf_counter()
        res = run('sine', c, rate_hz=10000.0, duration_s=1.0)
        wall = time.perf_counter() - t
        rows.append(('offline simulation, %s, 10 kHz' % c,
                     '%.1fx real time (%.1f us/period)' % (1.0 / wall,
                                                           wall / res.t.size * 1e6)))
    print('| measurement | value |')
    print('|---|---|')
    for k, v in rows:
        print('| %s | %s |' % (k, v))


if __name__ == '__main__':
    main()
