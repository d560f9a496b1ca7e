# SPDX-License-Identifier: Apache-2.0
"""
Offline closed loop: plant, setpoint, compensator, controller, driver, period by period.

:func:`run` follows the per-period order of docs/CONTRACTS.md exactly, so the ROS graph
in lockstep reproduces it sample for sample::

    y_k  = plant measurement (y_0 from reset, then the return of plant.step)
    r_k  = scenario reference at t_k = k / rate_hz, clamped to [0, reachable]
    ff_k = compensator.step(r_k)
    fb_k = controller.step(r_k, y_k)
    v_k  = driver.command(ff_k, fb_k, t_k)
    y_{k+1} = plant.step(v_k)

Controllers: ``open-loop`` (r times a linear gain, V/m), ``feedforward`` (inverse PI),
``pid`` (tuned plain PID), ``fuzzy`` (fuzzy PID), ``composite`` (inverse PI + fuzzy
PID, paper Figure 21), ``composite-pid`` (inverse PI + plain PID). Composite and
feedforward shape the reference (``config/compensator.yaml``) unless shaping is none.

The feedforward's PI model is by default the one held in ``config/compensator.yaml``
(the model the ROS compensator node uses), when it was identified on the simulated
plant (``model_plant``); for another plant it is identified from that plant's
hysteresis experiment (:func:`identified_model`). ``model=`` overrides both.

Metrics (:func:`metrics`) are computed by
:func:`fiber_align.simulation.metrics.loop_metrics`, the function ``fiber-align analyze``
applies to a bag, on the measured displacement (what the graph publishes) with the
``analyze`` settings of ``config/recorder.yaml``, so a lockstep bag of the same run
gives the same numbers (``analyze --skip`` = the run's ``tracking_skip_s``). The same
figures of the true tip position are reported under ``true_*`` keys.
"""

import copy
from dataclasses import dataclass, field
import itertools
import math
import os

import numpy as np

from fiber_align.config import config_path, ConfigError, load_params
from fiber_align.control.driver import DriverCore
from fiber_align.control.feedforward import Feedforward
from fiber_align.control.fuzzy_pid import FuzzyPid, make_pid, PlainPid
from fiber_align.control.shaping import design, Lead, ReferenceModel, Shaper, shaper_delay_s
from fiber_align.hysteresis.identify import identify
from fiber_align.hysteresis.pi import PIModel
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics
from fiber_align.plant.actuator import SimulatedActuator
from fiber_align.simulation import scenarios as scen
from fiber_align.simulation.metrics import loop_metrics

CONTROLLERS = ('open-loop', 'feedforward', 'pid', 'fuzzy', 'composite', 'composite-pid')
PLANTS = ('default', 'paper', 'linear', 'dense-pi', 'bouc-wen')
COMPENSATOR_FILE = 'compensator.yaml'
DESIGN_FILE = 'actuator.yaml'
COMPENSATOR_NODE = 'hysteresis_compensator'
IDENTIFY_RATE_HZ = 1000.0
IDENTIFY_DURATION_S = 10.0
_MODEL_CACHE = {}
_PARAMS_CACHE = {}
STEP_KEYS = ('settling_time_s', 'overshoot_pct', 'rise_time_s')
TRACK_KEYS = ('rms_error_m', 'max_error_m')


@dataclass
class SimResult:
    """Arrays of one run (SI: s, m, V) and its metrics (dict with SI keys)."""

    scenario: str
    controller: str
    rate_hz: float
    t: np.ndarray
    r: np.ndarray
    y_meas: np.ndarray
    y_true: np.ndarray
    v: np.ndarray
    ff: np.ndarray
    fb: np.ndarray
    gains: np.ndarray
    metrics: dict = field(default_factory=dict)

    def to_csv(self, path):
        """Write the arrays as CSV (one row per period; SI units in the header)."""
        cols = np.column_stack([self.t, self.r, self.y_meas, self.y_true, self.v, self.ff,
                                self.fb, self.gains])
        np.savetxt(path, cols, delimiter=',', comments='',
                   header='t_s,r_m,y_meas_m,y_true_m,v_v,ff_v,fb_v,kp_v_per_m,'
                          'ki_v_per_m_s,kd_v_s_per_m')


def cached_params(name, node):
    """
    Return :func:`fiber_align.config.load_params` of a params file, parsed once.

    The parsed file is kept per process, keyed by its path, size and modification time
    (an edited file is read again); a deep copy is returned.
    """
    try:
        path = config_path(name)
        st = os.stat(path)
    except (ConfigError, OSError):
        return load_params(name, node)
    key = (str(path), st.st_mtime_ns, st.st_size, node)
    if key not in _PARAMS_CACHE:
        _PARAMS_CACHE[key] = load_params(str(path), node)
    return copy.deepcopy(_PARAMS_CACHE[key])


def compensator_params(path=COMPENSATOR_FILE):
    """Return the ``hysteresis_compensator`` parameters (shaping, gain, model)."""
    return cached_params(path, COMPENSATOR_NODE)


def make_plant(plant, rate_hz, seed=0, noise=False, params=None):
    """
    Return a :class:`SimulatedActuator` of kind ``plant`` at ``rate_hz`` from plant.yaml.

    :param noise: False sets the sensor noise to 0 (the resolution stays).
    """
    if plant not in PLANTS:
        raise ValueError('unknown plant %r (allowed: %s)' % (plant, ', '.join(PLANTS)))
    p = dict(cached_params('plant.yaml', 'simulated_actuator') if params is None else params)
    p['hysteresis'] = plant
    p['seed'] = int(seed)
    if not noise:
        p['noise_rms_m'] = 0.0
    return SimulatedActuator.from_params(p, period_s=1.0 / float(rate_hz))


def hysteresis_experiment(plant='default', seed=0, noise=True, rate_hz=IDENTIFY_RATE_HZ,
                          peak_v=None):
    """
    Run the open-loop 0.1 Hz triangle on a plant; return ``(t, u, y_meas)`` (s, V, m).

    :param peak_v: top of the triangle (V); None is the paper's 72 V
        (scenario ``hysteresis-experiment``).
    """
    if peak_v is None:
        res = run('hysteresis-experiment', 'open-loop', rate_hz=rate_hz, seed=seed,
                  noise=noise, plant=plant, model=None)
        return res.t, res.v, res.y_meas
    p = make_plant(plant, rate_hz, seed, noise)
    n = int(round(IDENTIFY_DURATION_S * rate_hz))
    t = np.arange(n) / float(rate_hz)
    u = [float(peak_v) * scen.triangle_wave(scen.HYST_HZ * tk) for tk in t.tolist()]
    y = [p.reset()]
    step = p.step
    for uk in u[:-1]:
        y.append(step(uk))
    return t, np.array(u), np.array(y)


def identified_model(plant='default', seed=0, noise=True, peak_v=None, n_operators=10):
    """
    Return the PI model identified (lsq) from the plant's hysteresis experiment.

    The experiment (:func:`hysteresis_experiment`, 0.1 Hz triangle up to ``peak_v``, V)
    runs at 1 kHz for one 10 s period with the plant's sensor (noise on by default, as
    a measurement would be); thresholds by the identification's rule
    ``r_i = i / n max(u)``. Results are cached per argument set.
    """
    key = (plant, int(seed), bool(noise), peak_v, int(n_operators))
    if key not in _MODEL_CACHE:
        t, u, y = hysteresis_experiment(plant, seed, noise, peak_v=peak_v)
        _MODEL_CACHE[key] = identify(t, u, y, method='lsq',
                                     n_operators=int(n_operators)).model
    return _MODEL_CACHE[key]


def compensator_model(comp=None):
    """
    Return the PI model of the compensator parameters (``model_file`` or inline).

    :param comp: the ``hysteresis_compensator`` parameters (default
        ``config/compensator.yaml``).
    """
    comp = compensator_params() if comp is None else comp
    path = str(comp.get('model_file', '') or '')
    if path:
        return PIModel.load(path)
    return PIModel.from_params(comp)


def default_model(plant='default', comp=None):
    """
    Return the feedforward model used when none is given (see the module docstring).

    ``compensator.yaml``'s model when its ``model_plant`` is ``plant``; otherwise the
    model identified from ``plant``'s experiment with the same settings
    (:func:`compensator_identified_model`).
    """
    comp = compensator_params() if comp is None else comp
    if str(comp.get('model_plant', 'default')) == plant:
        return compensator_model(comp)
    return compensator_identified_model(plant, comp)


def identification_settings(comp=None):
    """
    Return ``(peak_v, n_operators)`` of the compensator's identification experiment.

    From ``identification_peak_v`` (V; None: the paper's 72 V) and
    ``identification_operators`` of the compensator parameters.
    """
    comp = compensator_params() if comp is None else comp
    v = comp.get('identification_peak_v')
    return (None if v is None else float(v)), int(comp.get('identification_operators', 10))


def compensator_identified_model(plant='default', comp=None):
    """Return the model identified on ``plant`` with the compensator's settings."""
    peak, n_ops = identification_settings(comp)
    return identified_model(plant, seed=0, noise=True, peak_v=peak, n_operators=n_ops)


def _load_model(model, plant, comp):
    """Resolve ``model`` (PIModel, path, ``'identify'`` or None) to a PIModel."""
    if isinstance(model, PIModel):
        return model
    if model is None:
        return default_model(plant, comp)
    if model in ('identify', 'identified'):
        return compensator_identified_model(plant, comp)
    return PIModel.load(model)


def make_shaper(comp, rate_hz, plant_obj):
    """Return the reference :class:`Shaper` configured in ``comp`` (or None)."""
    kind = str(comp.get('shaping', 'none'))
    if kind == 'none':
        return None
    wn = float(comp.get('shaping_omega_n_rad_s', 0.0))
    if wn <= 0:
        wn = design_dynamics(load_actuator(DESIGN_FILE))[0]
    zeta = float(comp.get('shaping_damping_ratio', 0.03))
    return Shaper(design(kind, wn, zeta, 1.0 / float(rate_hz)))


def build(controller, rate_hz, plant_obj, model=None, plant='default', seed=0, noise=False,
          controller_params=None, comp_params=None):
    """
    Return ``(compensator, feedback)`` objects for a controller name.

    The compensator has ``step(r) -> V``; the feedback has ``step(r, y) -> V``
    (or is None for open-loop controllers). ``model``: a PIModel, a params file,
    ``'identify'`` or None (:func:`default_model`); ``seed`` and ``noise`` are kept
    for compatibility and not used.
    """
    if controller not in CONTROLLERS:
        raise ValueError('unknown controller %r (allowed: %s)'
                         % (controller, ', '.join(CONTROLLERS)))
    comp = compensator_params() if comp_params is None else comp_params
    ctl = (cached_params('controller.yaml', 'fuzzy_pid_controller')
           if controller_params is None else controller_params)
    if controller == 'open-loop':
        return Feedforward(gain_v_per_m=float(comp['open_loop_gain_v_per_m'])), None
    if controller in ('feedforward', 'composite', 'composite-pid'):
        shaper = make_shaper(comp, rate_hz, plant_obj)
        ff = Feedforward(_load_model(model, plant, comp), shaper=shaper,
                         lead=make_lead(comp, rate_hz, shaper))
    else:
        ff = Feedforward(gain_v_per_m=0.0)
    if controller == 'feedforward':
        return ff, None
    refm = None
    if controller.startswith('composite') and str(
            ctl.get('composite_feedback_reference', 'model')) == 'model':
        refm = make_reference_model(comp, rate_hz)
    if controller in ('pid', 'composite-pid'):
        return ff, PlainPid(make_pid(ctl, rate_hz), refm)
    return ff, FuzzyPid.from_params(ctl, rate_hz, reference_filter=refm)


def make_reference_model(comp, rate_hz):
    """Return the composite feedback's :class:`ReferenceModel` (shaping from ``comp``)."""
    wn = float(comp.get('shaping_omega_n_rad_s', 0.0))
    if wn <= 0:
        wn = design_dynamics(load_actuator(DESIGN_FILE))[0]
    zeta = float(comp.get('shaping_damping_ratio', 0.03))
    shaper = make_shaper(comp, rate_hz, None)
    return ReferenceModel(shaper, wn, zeta, 1.0 / float(rate_hz),
                          lead=make_lead(comp, rate_hz, shaper))


def make_lead(comp, rate_hz, shaper):
    """Return the :class:`Lead` of ``comp`` (horizon: shaper delay + one period) or None."""
    if not bool(comp.get('delay_compensation', True)):
        return None
    period = 1.0 / float(rate_hz)
    return Lead(period, shaper_delay_s(shaper, period) + period,
                float(comp.get('delay_compensation_max_accel_m_per_s2', 0.01)))


def run(scenario, controller, rate_hz=None, duration_s=None, seed=0, noise=False,
        plant='default', model=None, plant_obj=None, controller_params=None,
        comp_params=None, driver_params=None, reference_scale=1.0, analyze_params=None):
    """
    Simulate one scenario with one controller; return a :class:`SimResult`.

    :param scenario: a name in :data:`fiber_align.simulation.scenarios.NAMES`.
    :param controller: a name in :data:`CONTROLLERS`.
    :param rate_hz: control rate (Hz); default ``rate_hz`` of config/controller.yaml.
    :param duration_s: run length (s); default the scenario's.
    :param seed: seed of the plant's sensor noise.
    :param noise: sensor noise on (the plant.yaml value) or off.
    :param plant: plant kind (``default`` = dense-pi truth, ``paper``, ``linear``, ...).
    :param model: feedforward PI model: a PIModel, a params file, ``'identify'``, or
        None for :func:`default_model` (compensator.yaml's model on its plant).
    :param plant_obj: a ready plant (overrides ``plant``, ``seed``, ``noise``).
    :param reference_scale: multiplies the reference (to test unreachable targets).
    :param analyze_params: metric settings (default the ``analyze`` node of
        ``config/recorder.yaml``: ``step_min_m``, ``settling_band``).
    """
    sc = scen.make(scenario)
    ctl_params = (cached_params('controller.yaml', 'fuzzy_pid_controller')
                  if controller_params is None else controller_params)
    rate = float(ctl_params.get('rate_hz', 1000.0) if rate_hz is None else rate_hz)
    if not rate > 0:
        raise ValueError('rate must be > 0 Hz, got %g' % rate)
    dur = sc.duration_s if duration_s is None else float(duration_s)
    if not dur > 0:
        raise ValueError('duration must be > 0 s, got %g' % dur)
    n = int(round(dur * rate))
    period = 1.0 / rate
    p = plant_obj if plant_obj is not None else make_plant(plant, rate, seed, noise)
    drv = DriverCore.from_params(cached_params('driver.yaml', 'actuator_driver')
                                 if driver_params is None else driver_params)
    reach = p.reachable_m()
    if sc.open_loop:
        loop = _run_open_loop(sc, n, period, p, drv)
        clamped = held = 0
    else:
        comp, fbc = build(controller, rate, p, model, plant, seed, noise, ctl_params,
                          comp_params)
        loop = _run_closed_loop(sc, n, period, p, drv, comp, fbc, reach, reference_scale)
        clamped, held = loop[-2:]
    t = np.arange(n) * period
    r, ym, yt, v, ffa, fba = (np.array(a, dtype=float) for a in loop[:6])
    gains = (np.fromiter(itertools.chain.from_iterable(loop[6]), float, 3 * n)
             if loop[6] else np.zeros(3 * n))
    res = SimResult(scenario, controller, rate, t, r, ym, yt, v, ffa, fba,
                    gains.reshape(n, 3))
    res.metrics = metrics(res, sc, (p.v_min, p.v_max), analyze_params)
    res.metrics.update({
        'scenario': scenario, 'controller': controller if not sc.open_loop else 'open-loop',
        'plant': plant, 'rate_hz': rate, 'duration_s': n * period, 'seed': int(seed),
        'noise': bool(noise), 'reachable_m': reach, 'reference_clamped_samples': clamped,
        'measurement_held_samples': held, 'driver_saturation_count': drv.saturation_count,
        'driver_slew_count': drv.slew_count})
    return res


def _run_open_loop(sc, n, period, p, drv):
    """Run an open-loop drive scenario; return the per-period lists (SI)."""
    r, ym, yt, v, ffa = [math.nan] * n, [], [], [], []
    y = p.reset()
    for k in range(n):
        tk = k * period
        ff = sc.drive(tk)
        vk = drv.command(ff, 0.0, tk)
        ym.append(y)
        yt.append(p.x)
        v.append(vk)
        ffa.append(ff)
        y = p.step(vk)
    return r, ym, yt, v, ffa, [0.0] * n, []


def _run_closed_loop(sc, n, period, p, drv, comp, fbc, reach, scale):
    """
    Run the per-period loop of docs/CONTRACTS.md; return the lists and the counters.

    The hot path of the offline simulation: bound methods and appends in locals, no
    numpy on scalars; the arithmetic is that of the core objects the ROS nodes call.
    """
    ref = sc.reference
    rs = [ref(k * period) * scale for k in range(n)]
    clamped = 0
    for k in range(n):
        rk = rs[k]
        if rk > reach:
            rs[k] = reach
            clamped += 1
        elif rk < 0.0:
            rs[k] = 0.0
            clamped += 1
    ym, yt, v, ffa, fba, gains = [], [], [], [], [], []
    held = 0
    comp_step = comp.step
    drv_command = drv.command
    p_step = p.step
    ym_add, yt_add, v_add = ym.append, yt.append, v.append
    ff_add, fb_add, g_add = ffa.append, fba.append, gains.append
    y = p.reset()
    if fbc is None:
        zero = (0.0, 0.0, 0.0)
        for k in range(n):
            ff = comp_step(rs[k])
            vk = drv_command(ff, 0.0, k * period)
            ym_add(y)
            yt_add(p.x)
            v_add(vk)
            ff_add(ff)
            fb_add(0.0)
            g_add(zero)
            y = p_step(vk)
        return rs, ym, yt, v, ffa, fba, gains, clamped, held
    fb_step = fbc.step
    nan0 = fbc.nan_count
    for k in range(n):
        rk = rs[k]
        ff = comp_step(rk)
        fb = fb_step(rk, y)
        vk = drv_command(ff, fb, k * period)
        ym_add(y)
        yt_add(p.x)
        v_add(vk)
        ff_add(ff)
        fb_add(fb)
        g_add(fbc.gains)
        y = p_step(vk)
    held = fbc.nan_count - nan0      # periods whose output was held (NaN error)
    return rs, ym, yt, v, ffa, fba, gains, clamped, held


def tracking_skip_s(sc, t):
    """
    Return the leading time (s) left out of the tracking metrics of scenario ``sc``.

    Step and staircase: the first half of the run (the settled part is scored); sine and
    triangle: the first period (``sc.skip_s``) when the run is longer than that.
    """
    span = float(t[-1] - t[0]) if t.size else 0.0
    if sc.name in ('step', 'staircase'):
        return 0.5 * span
    return sc.skip_s if span > sc.skip_s else 0.0


def metrics(res, sc, v_limits=None, params=None):
    """
    Return the metrics dict of a run (SI keys; keys that do not apply are None).

    All from :func:`fiber_align.simulation.metrics.loop_metrics` with the ``analyze``
    settings (``step_min_m``, ``settling_band``; default ``config/recorder.yaml``) and
    the tracking window :func:`tracking_skip_s`:

    * on the measured displacement (what the graph publishes, so a lockstep bag gives
      the same numbers): ``settling_time_s``, ``overshoot_pct``, ``rise_time_s`` (the
      worst over the setpoint steps), ``rms_error_m``, ``max_error_m``, ``steps`` (one
      dict per step), ``max_voltage_v``, ``saturation``, ``tracking_skip_s``;
    * on the true tip position: ``true_`` + the same scalar keys.
    """
    if params is None:
        params = cached_params('recorder.yaml', 'analyze')
    kw = {'step_min_m': float(params.get('step_min_m', 1e-6)),
          'band': float(params.get('settling_band', 0.02))}
    skip = tracking_skip_s(sc, res.t) if res.t.size else 0.0
    out = {'max_voltage_v': float(np.max(res.v)) if res.v.size else 0.0,
           'tracking_skip_s': skip}
    for prefix, y in (('', res.y_meas), ('true_', res.y_true)):
        for k in STEP_KEYS + TRACK_KEYS:
            out[prefix + k] = None
        if res.t.size < 2:
            continue
        lm = loop_metrics(res.t, res.r, y, res.v if not prefix else None, v_limits,
                          skip_s=skip, **kw)
        steps = lm.get('steps', [])
        for k in STEP_KEYS:
            vals = [st[k] for st in steps]
            out[prefix + k] = max(vals) if vals else None
        tr = lm.get('tracking')
        if tr:
            for k in TRACK_KEYS:
                out[prefix + k] = tr[k]
        if not prefix:
            out['steps'] = steps
            if 'saturation' in lm:
                out['saturation'] = lm['saturation']
                out['max_voltage_v'] = lm['saturation'].get('v_max_seen_v',
                                                            out['max_voltage_v'])
    return out


def check_model_file(path):
    """Raise ConfigError unless ``path`` holds a PI model."""
    try:
        PIModel.load(path)
    except (OSError, ValueError) as exc:
        raise ConfigError('cannot load model %s: %s' % (path, exc)) from None
