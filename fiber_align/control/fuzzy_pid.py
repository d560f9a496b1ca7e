# SPDX-License-Identifier: Apache-2.0
"""
Fuzzy self-tuning PID (SEED-NOTES section 6) and the gain tables per control rate.

Each period, with error ``e = r - y`` (m) and its filtered rate ``de`` (m/s, the PID's
derivative filter):

* fuzzy inputs ``E = e_scale_per_m * e`` and ``EC = ec_scale_s_per_m * de`` (the input
  scale factors, or quantisation gains: 1e6 per m makes E micrometres, 1e3 s/m makes EC
  micrometres per millisecond), clamped to the domains [-12, 12] and [-20, 20];
* Mamdani inference gives ``dkp, dki, dkd`` on [-6, 6], [-4, 4], [-3, 3];
* ``kp = kp0 + 0.8 dkp kp_unit``, ``ki = ki0 + 0.8 dki ki_unit``,
  ``kd = kd0 + 0.6 dkd kd_unit`` (the paper's output scale factors 0.8, 0.8, 0.6; the
  units kp_unit in V/m, ki_unit in V/(m s), kd_unit in V s/m turn the paper's
  dimensionless increments into SI gains);
* the PID law of :mod:`fiber_align.control.pid` runs with these gains.

The gains depend on the control rate (a 10 kHz loop can damp the 1.4 kHz mode with its
derivative, a 1 kHz loop cannot), so ``config/controller.yaml`` lists them per rate in
``gain_rates_hz``; :func:`gains_for_rate` picks the entry for the loop's rate.
"""

import math

from fiber_align.config import ConfigError, load_params
from fiber_align.control.fuzzy import FuzzyInference
from fiber_align.control.fuzzy_surface import FuzzySurface
from fiber_align.control.pid import Pid

CONFIG_FILE = 'controller.yaml'
CONFIG_NODE = 'fuzzy_pid_controller'


# The limits and anti-windup keys of the controller parameters (config/controller.yaml).
LIMIT_KEYS = ('u_min', 'u_max', 'anti_windup', 'tracking_time_s')


def _param(params, key):
    """Return ``params[key]``; a missing key is a ConfigError naming the file and the key."""
    try:
        return params[key]
    except KeyError:
        raise ConfigError('%s: node %s lacks %s' % (CONFIG_FILE, CONFIG_NODE, key)) from None


def gains_for_rate(params, section, rate_hz):
    """
    Return ``(mapping, rate_used)``: the entries of ``params[section]`` for ``rate_hz``.

    Every list-valued entry of the section is indexed by the position of the nearest rate
    (by ratio) in ``params['gain_rates_hz']``; scalar entries are taken as they are.
    """
    rates = [float(x) for x in params.get('gain_rates_hz', [])]
    sec = params.get(section)
    if not rates or not isinstance(sec, dict):
        raise ConfigError('%s needs gain_rates_hz and a %s section' % (CONFIG_FILE, section))
    i = min(range(len(rates)), key=lambda k: abs(math.log(rates[k] / float(rate_hz))))
    out = {}
    for k, v in sec.items():
        if isinstance(v, (list, tuple)):
            if len(v) != len(rates):
                raise ConfigError('%s.%s has %d entries for %d gain_rates_hz'
                                  % (section, k, len(v), len(rates)))
            out[k] = v[i]
        else:
            out[k] = v
    return out, rates[i]


def make_pid(params, rate_hz):
    """Return the tuned plain :class:`Pid` for ``rate_hz`` from controller parameters."""
    g, _ = gains_for_rate(params, 'pid', rate_hz)
    for k in LIMIT_KEYS:
        if k not in g:
            g[k] = _param(params, k)
    return Pid.from_params(g, 1.0 / float(rate_hz))


def surface_for(params, fis=None, surface=None):
    """
    Return the fuzzy surface the controller parameters ask for, or None (exact inference).

    :param params: ``fuzzy_pid_controller`` parameters (``fuzzy.surface_intervals``: 0 for
        none, else an even ``q``).
    :param fis: their :class:`~fiber_align.control.fuzzy.FuzzyInference` (None: built).
    :param surface: a surface built before, returned when it :meth:`matches
        <fiber_align.control.fuzzy_surface.FuzzySurface.matches>` (building one takes ~0.1 s).
    """
    fz = params['fuzzy']
    q = int(fz['surface_intervals'])
    if not q:
        return None
    fis = FuzzyInference.from_params(fz) if fis is None else fis
    if surface is not None and surface.matches(fis, q):
        return surface
    return FuzzySurface(fis, q)


class FuzzyPid:
    """
    Fuzzy self-tuning PID: ``step(r, y)`` (m, m) returns the feedback voltage (V).

    :param fis: the :class:`FuzzyInference` (paper units).
    :param pid: the :class:`Pid` whose gains are rescheduled every period.
    :param kp0: base gains (V/m).
    :param ki0: base integral gain (V/(m s)).
    :param kd0: base derivative gain (V s/m).
    :param units: ``(kp_unit, ki_unit, kd_unit)`` in V/m, V/(m s), V s/m.
    :param output_scale: the paper's scale factors ``(0.8, 0.8, 0.6)``.
    :param e_scale_per_m: E per metre of error (1/m).
    :param ec_scale_s_per_m: EC per m/s of error rate (s/m).
    :param enabled: False freezes the gains at kp0, ki0, kd0 (a plain PID).
    :param reference_filter: optional object with ``step(r) -> m`` and ``reset()``
        (a :class:`fiber_align.control.shaping.ReferenceModel`) whose output replaces
        the reference in the error, as the composite controller does.
    :param surface: None evaluates the exact closed-form inference every period; a
        :class:`~fiber_align.control.fuzzy_surface.FuzzySurface` of ``fis`` interpolates its
        tables (error bound :func:`~fiber_align.control.fuzzy_surface.surface_error_bound`).
    """

    def __init__(self, fis, pid, kp0, ki0, kd0, units, output_scale=(0.8, 0.8, 0.6),
                 e_scale_per_m=1e6, ec_scale_s_per_m=1e3, enabled=True,
                 reference_filter=None, surface=None):
        """Store the parts; gains start at the base values."""
        self.reference_filter = reference_filter
        self.fis = fis
        self.pid = pid
        self.base = (float(kp0), float(ki0), float(kd0))
        self.units = tuple(float(u) for u in units)
        self.output_scale = tuple(float(s) for s in output_scale)
        self.e_scale = float(e_scale_per_m)
        self.ec_scale = float(ec_scale_s_per_m)
        self.enabled = bool(enabled)
        self.surface = surface
        # gain_o = g_o0 + g_o1 * M_o / A_o (area A and moment M of the aggregated set
        # about the domain centre, see FuzzyInference.area_moment)
        g = []
        for b, u, sc, (lo, h) in zip(self.base, self.units, self.output_scale, fis._out):
            g += [b + sc * u * (lo + 3.0 * h), sc * u * h]
        self._g = tuple(g)
        self.reset()

    @classmethod
    def from_params(cls, params, rate_hz, enabled=True, reference_filter=None, surface=None):
        """
        Build from the ``fuzzy_pid_controller`` parameters for a control rate (Hz).

        :param surface: a :class:`~fiber_align.control.fuzzy_surface.FuzzySurface` built before;
            used when it tabulates these rules with ``fuzzy.surface_intervals``
            (:func:`surface_for`), otherwise a new one is built.
        """
        fz = params.get('fuzzy')
        if not isinstance(fz, dict):
            raise ConfigError('%s lacks the fuzzy section' % CONFIG_FILE)
        g, _ = gains_for_rate(params, 'fuzzy_pid', rate_hz)
        try:
            pid = Pid(g['kp0'], g['ki0'], g['kd0'], 1.0 / float(rate_hz),
                      derivative_filter_hz=float(g['derivative_filter_hz']),
                      u_min=float(_param(params, 'u_min')),
                      u_max=float(_param(params, 'u_max')),
                      anti_windup=str(_param(params, 'anti_windup')),
                      tracking_time_s=float(_param(params, 'tracking_time_s')))
            fis = FuzzyInference.from_params(fz)
            return cls(fis, pid, g['kp0'], g['ki0'], g['kd0'],
                       (g['kp_unit'], g['ki_unit'], g['kd_unit']),
                       output_scale=fz['output_scale'], e_scale_per_m=fz['e_scale_per_m'],
                       ec_scale_s_per_m=fz['ec_scale_s_per_m'], enabled=enabled,
                       reference_filter=reference_filter,
                       surface=surface_for(params, fis, surface))
        except KeyError as exc:
            raise ConfigError('fuzzy_pid gains lack %s' % exc) from None

    @classmethod
    def from_config(cls, rate_hz, path=CONFIG_FILE, enabled=True):
        """Build from ``config/controller.yaml`` for a control rate (Hz)."""
        return cls.from_params(load_params(path, CONFIG_NODE), rate_hz, enabled)

    def gain_bounds(self):
        """Return ``[(lo, hi)] * 3``: the range of kp, ki, kd the fuzzy layer can produce."""
        out = []
        for b, u, s, (lo, hi) in zip(self.base, self.units, self.output_scale,
                                     self.fis.out_domains):
            a, c = b + s * u * lo, b + s * u * hi
            out.append((min(a, c), max(a, c)))
        return out

    def reset(self):
        """Return to rest with the base gains."""
        self.pid.reset()
        if self.reference_filter is not None:
            self.reference_filter.reset()
        self.pid.set_gains(*self.base)
        self.gains = self.base
        self.u = 0.0
        self.held = False
        self.nan_count = 0

    def schedule(self, e, ec):
        """Return the gains ``(kp, ki, kd)`` (SI) for fuzzy inputs E, EC (fuzzy units)."""
        if self.surface is not None:
            return self.surface.gains(e, ec, self._g)
        dk = self.fis.evaluate(e, ec)
        b, un, sc = self.base, self.units, self.output_scale
        return (b[0] + sc[0] * dk[0] * un[0], b[1] + sc[1] * dk[1] * un[1],
                b[2] + sc[2] * dk[2] * un[2])

    def step(self, r, y):
        """
        Advance one period: reference ``r`` (m), measurement ``y`` (m) -> voltage (V).

        A NaN reference or measurement holds the previous output and sets :attr:`held`.
        """
        rf = self.reference_filter
        if rf is not None:
            r = rf.step(r)
        e = r - y
        if e - e != 0.0:            # NaN or infinite
            self.nan_count += 1
            self.held = True
            return self.u
        self.held = False
        pid = self.pid
        if self.enabled:
            # rate of the error for EC: the PID's filtered derivative as of last period
            surf = self.surface
            if surf is not None:
                g = surf.gains(self.e_scale * e, self.ec_scale * pid.deriv, self._g)
            else:
                g = self.schedule(self.e_scale * e, self.ec_scale * pid.deriv)
            pid.kp, pid.ki, pid.kd = g
            self.gains = g
        u = self.u = pid.step(e)
        return u


def carry_state(old, new):
    """
    Give the feedback law ``new`` the running state of ``old`` (a live retune); return it.

    The PID's integral, filtered derivative, last error and output, the law's output and
    its reference model carry over, so a change of gains or limits is bumpless. Both
    are :class:`FuzzyPid` or :class:`PlainPid`.
    """
    o, n = old.pid, new.pid
    n.integral, n.deriv, n.e_prev, n.u = o.integral, o.deriv, o.e_prev, o.u
    new.u = old.u
    if old.reference_filter is not None:
        new.reference_filter = old.reference_filter
    return new


class PlainPid:
    """A :class:`Pid` behind the same ``step(r, y)`` interface as :class:`FuzzyPid`."""

    def __init__(self, pid, reference_filter=None):
        """Wrap ``pid``; ``reference_filter`` as in :class:`FuzzyPid`."""
        self.pid = pid
        self.reference_filter = reference_filter
        self.reset()

    def reset(self):
        """Return to rest."""
        self.pid.reset()
        if self.reference_filter is not None:
            self.reference_filter.reset()
        self.gains = (self.pid.kp, self.pid.ki, self.pid.kd)
        self.u = 0.0
        self.held = False
        self.nan_count = 0

    def step(self, r, y):
        """Advance one period: reference (m), measurement (m) -> voltage (V)."""
        if self.reference_filter is not None:
            r = self.reference_filter.step(r)
        e = r - y
        if not math.isfinite(e):
            self.nan_count += 1
            self.held = True
            return self.u
        self.held = False
        self.u = self.pid.step(e)
        return self.u
