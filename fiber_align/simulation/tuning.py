# SPDX-License-Identifier: Apache-2.0
"""
Re-runnable gain search, the linearised stability check, and the compensator model.

``python -m fiber_align.simulation.tuning [--rate HZ]`` grid-searches the plain PID on the
plant without hysteresis (the paper's Figure 20 case, noise off): it keeps the gain sets
whose linearised closed loop is stable for a plant slope from 0.5 to 1.5 times the
design's alpha (the hysteresis changes the local slope) and whose 82 um step overshoots
by at most 2 %, and prints the one with the shortest 2 % settling time. Gains are
searched as loop gains (gain times alpha: 1/s for ki, s for kd) and printed in SI.

``python -m fiber_align.simulation.tuning --compensator [--output PATH]`` identifies the
feedforward model (lsq, ``identification_operators`` operators) from the hysteresis
experiment (0.1 Hz triangle up to ``identification_peak_v``, 1 kHz, sensor noise on,
seed 0) on the default simulated plant and writes it inline into
``config/compensator.yaml`` (thresholds_v, weights_m_per_v, model_source, model_plant;
the rest of the file, comments included, is kept). The ROS compensator node and
``fiber-align simulate`` both use that model.
"""

import argparse
import itertools
import re

import numpy as np

from fiber_align.config import config_path, load_params
from fiber_align.control.pid import Pid
from fiber_align.hysteresis.pi import PIModel
from fiber_align.hysteresis.truth import Linear
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics, discretise
from fiber_align.plant.actuator import SimulatedActuator
from fiber_align.simulation import simulate
from fiber_align.simulation.metrics import step_metrics


def closed_loop_matrix(kp, ki, kd, derivative_filter_hz, period_s, omega_n, zeta, alpha):
    """
    Return the state matrix of the linearised loop (plant mode + PID), reference 0.

    State ``[x (m), x' (m/s), I (V), d (m/s), e_prev (m)]``; the plant is ``alpha`` (m/V)
    times the exactly discretised mode, the controller is one period of the real
    :class:`fiber_align.control.pid.Pid` without limits (linear in the state), applied
    to each unit state to give the matrix's columns.
    """
    ad, bd = discretise(omega_n, zeta, period_s)
    pid = Pid(kp, ki, kd, period_s, derivative_filter_hz)

    def f(z):
        x, xd, integ, d, ep = z
        pid.integral, pid.deriv, pid.e_prev = integ, d, ep
        u = pid.step(-x)
        xn = ad @ np.array([x, xd]) + bd * alpha * u
        return np.array([xn[0], xn[1], pid.integral, pid.deriv, pid.e_prev])
    return np.column_stack([f(col) for col in np.eye(5)])


def spectral_radius(*args):
    """Return the largest pole magnitude of :func:`closed_loop_matrix` (< 1: stable)."""
    return float(np.max(np.abs(np.linalg.eigvals(closed_loop_matrix(*args)))))


def step_settling(kp, ki, kd, fd, rate_hz, omega_n, alpha, zeta=0.03, duration_s=0.04):
    """Return ``(settling_s, overshoot_pct)`` of an 82 um step on the linear plant."""
    period = 1.0 / rate_hz
    p = SimulatedActuator(period, Linear(alpha), omega_n, zeta, v_min=-20, v_max=100)
    c = Pid(kp, ki, kd, period, fd, -100, 100)
    y = p.reset()
    ys = []
    for _ in range(int(duration_s * rate_hz)):
        ys.append(p.x)
        y = p.step(c.step(82e-6 - y))
    m = step_metrics(np.arange(len(ys)) * period, np.array(ys), 82e-6)
    return m['settling_time_s'], m['overshoot_pct']


def search(rate_hz, zeta=0.03):
    """Grid-search the PID at ``rate_hz``; return a list of (settling, overshoot, gains)."""
    wn, alpha = design_dynamics(load_actuator())
    period = 1.0 / rate_hz
    kia = [50, 100, 150, 200, 300, 400, 600, 800, 1000, 1400, 2000]
    kpa = [-0.1, 0.0, 0.1, 0.2]
    kda = [0.0, 5e-5, 1e-4, 1.5e-4] if rate_hz > 2000 else [0.0]
    fds = [3000.0] if rate_hz > 2000 else [0.0]
    out = []
    for ki, kp, kd, fd in itertools.product(kia, kpa, kda, fds):
        g = (kp / alpha, ki / alpha, kd / alpha)
        if any(spectral_radius(*g, fd, period, wn, zeta, alpha * s) >= 0.999
               for s in (0.5, 1.0, 1.5)):
            continue
        st, ov = step_settling(*g, fd, rate_hz, wn, alpha, zeta)
        if ov <= 2.0:
            out.append((st, ov, g + (fd,)))
    out.sort(key=lambda x: x[0])
    return out


def yaml_float(v):
    """
    Return the shortest exact text of a float that YAML 1.1 and ROS read as a double.

    ``repr`` round-trips exactly; a mantissa without a dot (``1e-07``) would be read as
    a string by PyYAML, so one is added (``1.0e-07``).
    """
    s = repr(float(v))
    if 'e' in s:
        mant, exp = s.split('e')
        if '.' not in mant:
            mant += '.0'
        return '%se%s' % (mant, exp if exp[0] in '+-' else '+' + exp)
    return s if '.' in s or 'n' in s else s + '.0'


def _flow_list(values, indent, width=92):
    """Return a YAML flow list of exact floats (:func:`yaml_float`), wrapped at ``width``."""
    items = [yaml_float(v) for v in values]
    lines, cur = [], ''
    for it in items:
        piece = it if not cur else cur + ', ' + it
        if len(piece) + indent > width and cur:
            lines.append(cur + ',')
            cur = it
        else:
            cur = piece
    lines.append(cur)
    return ('\n' + ' ' * indent).join(lines)


def update_compensator_text(text, model, source, plant):
    """
    Return ``text`` (compensator.yaml) with the inline model replaced by ``model``.

    Replaces the ``thresholds_v``, ``weights_m_per_v``, ``model_source`` and
    ``model_plant`` entries of the file (adding ``model_plant`` after ``model_source``
    when it is missing); everything else, comments included, is kept.
    """
    def put_list(txt, key, values):
        pat = re.compile(r'^(?P<ind>[ \t]*)%s:[ \t]*\[[^\]]*\]' % key, re.M)
        m = pat.search(txt)
        if m is None:
            raise ValueError('compensator file has no %s: [...] entry' % key)
        ind = m.group('ind')
        head = '%s%s: [' % (ind, key)
        body = _flow_list(values, len(head))
        return txt[:m.start()] + head + body + ']' + txt[m.end():]

    def put_scalar(txt, key, value, after=None):
        # a value is a plain word or a double-quoted string; a trailing comment is kept
        pat = re.compile(r'^(?P<ind>[ \t]*)%s:[ \t]*(?:"[^"\n]*"|[^ \t#\n]*)' % key, re.M)
        m = pat.search(txt)
        if m is not None:
            return txt[:m.start()] + '%s%s: %s' % (m.group('ind'), key, value) + txt[m.end():]
        m = re.compile(r'^(?P<ind>[ \t]*)%s:.*$' % after, re.M).search(txt)
        if m is None:
            raise ValueError('compensator file has no %s entry' % after)
        return (txt[:m.end()] + '\n%s%s: %s' % (m.group('ind'), key, value)
                + txt[m.end():])

    text = put_list(text, 'thresholds_v', model.thresholds)
    text = put_list(text, 'weights_m_per_v', model.weights)
    text = put_scalar(text, 'model_source', '"%s"' % source.replace('"', "'"))
    return put_scalar(text, 'model_plant', plant, after='model_source')


def write_compensator(path=None, plant='default'):
    """
    Identify the compensator model on ``plant`` and write it into ``path``; return it.

    :param path: the compensator params file (default ``config/compensator.yaml``).
    :param plant: plant kind the experiment runs on (``default``).
    """
    path = config_path('compensator.yaml') if path is None else path
    comp = load_params(path, simulate.COMPENSATOR_NODE)
    setup = simulate.load_setup(compensator=path)
    peak, n_ops = simulate.identification_settings(comp)
    model = simulate.compensator_identified_model(plant, setup)
    source = ('lsq %d operators, 0.1 Hz 0-%g V triangle on the %s plant (1 kHz, noise, '
              'seed 0)' % (n_ops, 72.0 if peak is None else peak, plant))
    with open(path, encoding='utf-8') as f:
        text = f.read()
    text = update_compensator_text(text, model, source, plant)
    with open(path, 'w', encoding='utf-8') as f:
        f.write(text)
    back = PIModel.load(str(path), simulate.COMPENSATOR_NODE)
    if not (np.array_equal(back.thresholds, model.thresholds)
            and np.array_equal(back.weights, model.weights)):
        raise RuntimeError('%s does not read back the identified model' % path)
    return model


def main(argv=None):
    """Print the best gains for each rate, or regenerate the compensator model."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    ap.add_argument('--rate', type=float, action='append', help='control rate, Hz')
    ap.add_argument('--compensator', action='store_true',
                    help='identify the feedforward model and write compensator.yaml')
    ap.add_argument('--output', default=None,
                    help='compensator params file to update (default: '
                         'config/compensator.yaml)')
    args = ap.parse_args(argv)
    if args.compensator:
        model = write_compensator(args.output)
        print('wrote %d operators: thresholds_v %s' % (model.n, model.thresholds.tolist()))
        print('weights_m_per_v %s' % model.weights.tolist())
        return 0
    for rate in args.rate or [1000.0, 10000.0]:
        res = search(rate)
        print('rate %g Hz: %d stable candidates' % (rate, len(res)))
        for st, ov, g in res[:5]:
            print('  settling %.2f ms overshoot %.2f %%  kp %.6g ki %.6g kd %.6g fd %g'
                  % ((st * 1e3, ov) + g))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
