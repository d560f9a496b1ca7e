# SPDX-License-Identifier: Apache-2.0
"""
What a node's parameter value must mean, beyond its type and range: pure checks.

The nodes call these from their start-up and their on-set-parameters callbacks; each
returns ``None`` or the one-line reason of a refusal, which names the parameter and the
values it allows (SI: V, m, m/V, Hz, s, V/s).

- :func:`feedback_limits`: the feedback's output limits ``u_min``, ``u_max`` against the
  drive the setpoint range needs: a feedback law that drives alone (``pid``, ``fuzzy``)
  must reach the voltage of every setpoint (setpoint / the design gain ``alpha``); one
  beside a feedforward (``composite``, ``composite-pid``) corrects in both directions
  (``u_min < 0 < u_max``); always ``u_min < u_max``.
- :func:`controller_values`: every live value of the controller (ranges, choices, one gain
  entry per ``gain_rates_hz``, the fuzzy section's sizes, the limits above).
- :func:`model_file`, :func:`pi_model`: a model parameter names a readable, invertible
  PI model (a file parameter a readable file).
- :func:`protections_off`: the driver's protections a set of values turns off (accepted,
  but reported as a WARN).
"""

import math
import os

from fiber_align.config import config_dir, ConfigError
from fiber_align.control.factory import check_param, FEEDFORWARD_ONLY
from fiber_align.control.pid import ANTI_WINDUP
from fiber_align.hysteresis.pi import NotInvertibleError, PIModel

#: Controllers whose feedback drives alone (no feedforward beside it).
FEEDBACK_ALONE = ('pid', 'fuzzy')
#: Allowed strings of the controller's choice parameters.
CHOICES = {'anti_windup': ANTI_WINDUP, 'composite_feedback_reference': ('model', 'raw')}
#: The sections of the controller whose list entries are one per ``gain_rates_hz``.
GAIN_SECTIONS = ('pid', 'fuzzy_pid')


def _seq(v):
    """Return True for a list-like parameter value (list, tuple, array)."""
    return not isinstance(v, (str, bytes, dict)) and hasattr(v, '__len__')


def feedback_limits(u_min, u_max, controller, setpoint_min_m, setpoint_max_m,
                    alpha_m_per_v):
    """
    Return ``None`` or why the feedback limits ``u_min``, ``u_max`` (V) make no sense.

    :param controller: the graph's controller (a name of ``control.factory.CONTROLLERS``).
    :param setpoint_min_m: lowest accepted setpoint (m); ``setpoint_max_m`` the highest.
    :param alpha_m_per_v: the design gain (m/V): a setpoint r needs about r / alpha volts.
    """
    u_min, u_max = float(u_min), float(u_max)
    if not u_min < u_max:
        return ('u_min=%g V must be below u_max=%g V (allowed: u_min < u_max)'
                % (u_min, u_max))
    if controller in FEEDBACK_ALONE:
        need_hi = float(setpoint_max_m) / float(alpha_m_per_v)
        need_lo = min(0.0, float(setpoint_min_m) / float(alpha_m_per_v))
        if u_max < need_hi:
            return ('u_max=%g V is below the %.1f V the setpoint range needs (controller '
                    '%s drives alone: setpoint_max_m %.1f um at the design gain %.3f um/V; '
                    'allowed: u_max >= %.1f V)' % (u_max, need_hi, controller,
                                                   setpoint_max_m * 1e6,
                                                   alpha_m_per_v * 1e6, need_hi))
        if u_min > need_lo:
            return ('u_min=%g V is above the %.1f V the setpoint range needs (controller '
                    '%s drives alone: setpoint_min_m %.1f um; allowed: u_min <= %.1f V)'
                    % (u_min, need_lo, controller, setpoint_min_m * 1e6, need_lo))
        return None
    if controller in FEEDFORWARD_ONLY:
        return None                     # no feedback law: the limits are unused
    if not u_max > 0.0:
        return ('u_max=%g V leaves the feedback no push towards a higher setpoint (the '
                'feedforward of %s needs a correction both ways; allowed: u_max > 0 V)'
                % (u_max, controller))
    if not u_min < 0.0:
        return ('u_min=%g V leaves the feedback no push towards a lower setpoint (the '
                'feedforward of %s needs a correction both ways; allowed: u_min < 0 V)'
                % (u_min, controller))
    return None


def gain_tables(params):
    """Return ``None`` or why the controller's gain lists do not match ``gain_rates_hz``."""
    rates = params.get('gain_rates_hz')
    if not _seq(rates) or not len(rates):
        return 'gain_rates_hz=%r: allowed: a non-empty list of rates (Hz)' % (rates,)
    for sec in GAIN_SECTIONS:
        for k, v in (params.get(sec) or {}).items():
            if _seq(v) and len(v) != len(rates):
                return ('%s.%s has %d entries for %d gain_rates_hz (allowed: one entry per '
                        'rate of gain_rates_hz %s)' % (sec, k, len(v), len(rates),
                                                       list(rates)))
    return None


def fuzzy_values(fz):
    """Return ``None`` or why the ``fuzzy`` section's sizes make no sense."""
    scale = fz.get('output_scale')
    if _seq(scale) and len(scale) != 3:
        return ('fuzzy.output_scale has %d entries (allowed: 3, the scale factors of kp, ki '
                'and kd, each in [0, 10])' % len(scale))
    q = fz.get('surface_intervals')
    if q is not None and (int(q) != q or q < 0 or (q and int(q) % 2)):
        return ('fuzzy.surface_intervals=%r (allowed: 0, the exact inference, or an even '
                'number >= 2)' % (q,))
    for key in ('e_domain', 'ec_domain', 'dkp_domain', 'dki_domain', 'dkd_domain'):
        dom = fz.get(key)
        if _seq(dom) and (len(dom) != 2 or not dom[0] < dom[1]):
            return 'fuzzy.%s=%r (allowed: [lo, hi] with lo < hi)' % (key, list(dom))
    return None


def controller_values(changes, params, controller, setpoint_min_m, setpoint_max_m,
                      alpha_m_per_v):
    """
    Return ``None`` or why a change of the controller's parameters is refused.

    :param changes: ``{dotted name: value}`` being set.
    :param params: the controller's parameters with the changes applied (nested).
    :param controller: the graph's controller; the setpoint range (m) and the design
        gain (m/V) as :func:`feedback_limits`.
    """
    for name, value in changes.items():
        why = check_param(name, value)
        if why:
            return why
        key = name.split('.')[-1]
        if key in CHOICES and value not in CHOICES[key]:
            return '%s=%r: allowed: %s' % (name, value, ', '.join(CHOICES[key]))
    why = gain_tables(params) or fuzzy_values(params.get('fuzzy') or {})
    if why:
        return why
    return feedback_limits(params['u_min'], params['u_max'], controller, setpoint_min_m,
                           setpoint_max_m, alpha_m_per_v)


def model_file(value, name='model_file'):
    """
    Return ``None`` or why ``value`` is no readable PI model params file.

    ``''`` (the inline model) is allowed; else a path, or a name in ``config/``, of a
    readable params file holding an invertible model (``thresholds_v``,
    ``weights_m_per_v``).
    """
    allowed = ("allowed: '' for the inline model, or a readable PI model params file "
               "(a path, or a name in %s)" % config_dir())
    if value == '':
        return None
    if not isinstance(value, str):
        return '%s=%r is not a file name (%s)' % (name, value, allowed)
    path = value if os.path.isfile(value) else os.path.join(str(config_dir()), value)
    if not os.path.isfile(path) or not os.access(path, os.R_OK):
        return '%s=%r: no readable file there (%s)' % (name, value, allowed)
    try:
        PIModel.load(path).inverse()
    except (ConfigError, NotInvertibleError, ValueError, KeyError, TypeError) as exc:
        return '%s=%r holds no usable PI model: %s (%s)' % (name, value, exc, allowed)
    return None


def pi_model(thresholds_v, weights_m_per_v):
    """Return ``None`` or why the inline model (``thresholds_v``, ``weights_m_per_v``) is bad."""
    allowed = ('allowed: equally long lists, thresholds_v >= 0 V ascending, weights_m_per_v '
               'with positive partial sums (an invertible model)')
    try:
        r = [float(x) for x in thresholds_v]
        w = [float(x) for x in weights_m_per_v]
    except (TypeError, ValueError):
        return 'thresholds_v, weights_m_per_v must be lists of numbers (%s)' % allowed
    if not r or len(r) != len(w):
        return ('thresholds_v has %d entries, weights_m_per_v %d (%s)'
                % (len(r), len(w), allowed))
    if not all(math.isfinite(x) for x in r + w) or r[0] < 0 or \
            any(b <= a for a, b in zip(r, r[1:])):
        return 'thresholds_v=%r (%s)' % (r, allowed)
    try:
        PIModel(r, w).inverse()
    except (NotInvertibleError, ValueError) as exc:
        return 'weights_m_per_v=%r: %s (%s)' % (w, exc, allowed)
    return None


#: The driver's protections: parameter -> (is it off for this value, what is lost).
PROTECTIONS = {
    'watchdog_timeout_s': (lambda v: float(v) <= 0.0,
                           'the watchdog is off: a silent input no longer ramps the '
                           'output to the safe voltage'),
    'latch_trips': (lambda v: int(v) == 0,
                    'the watchdog latch is off: a loop that keeps losing its input cycles '
                    'between the safe voltage and its resumes'),
    'slew_rate_v_per_s': (lambda v: float(v) <= 0.0 or not math.isfinite(float(v)),
                          'the slew limit is off: steps reach the actuator unlimited'),
}


def protections_off(params):
    """Return ``{name: text}`` of the protections ``params`` (the driver's values) turn off."""
    out = {}
    for name, (off, text) in PROTECTIONS.items():
        if name in params and off(params[name]):
            out[name] = '%s=%r: %s' % (name, params[name], text)
    return out


def protections_off_texts(params_by_axis):
    """Return the texts of the protections any axis's values turn off, once each, in order."""
    return list(dict.fromkeys(t for p in params_by_axis for t in protections_off(p).values()))
