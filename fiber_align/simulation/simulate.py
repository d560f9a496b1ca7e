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

Controllers: :data:`fiber_align.control.factory.CONTROLLERS`, built by that factory (the
one the ROS nodes call). Composite and feedforward shape the reference
(``config/compensator.yaml``) unless shaping is none.

Configuration is read once per :func:`run` (or once by the caller, :func:`load_setup`,
and passed down as a :class:`Setup`); nothing is kept between calls.

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

from dataclasses import dataclass, field
import itertools
import math

import numpy as np

from fiber_align.config import ConfigError, load_params
from fiber_align.control.driver import DriverCore
from fiber_align.control.factory import build_controller, build_feedforward, MODEL_CONTROLLERS
from fiber_align.control.fuzzy_pid import surface_for
from fiber_align.design import load_actuator
from fiber_align.design.mode import design_dynamics
from fiber_align.hysteresis.identify import identify
from fiber_align.hysteresis.pi import PIModel
from fiber_align.plant.actuator import KINDS as PLANTS, SimulatedActuator
from fiber_align.simulation import scenarios as scen
from fiber_align.simulation.loop import ClosedLoop
from fiber_align.simulation.metrics import (loop_metrics, run_scores, step_settings,
                                            STEP_KEYS, TRACK_KEYS)

COMPENSATOR_FILE = 'compensator.yaml'
# The generated feedforward model (tuning --compensator), read after compensator.yaml.
MODEL_FILE = 'models/compensator_model.yaml'
COMPENSATOR_NODE = 'hysteresis_compensator'
DESIGN_FILE = 'actuator.yaml'
IDENTIFY_RATE_HZ = 1000.0
IDENTIFY_DURATION_S = 10.0
# The params files an offline run reads: Setup field -> (file, node).
SETUP_FILES = {
    'plant': ('plant.yaml', 'simulated_actuator'),
    'controller': ('controller.yaml', 'fuzzy_pid_controller'),
    'compensator': (COMPENSATOR_FILE, COMPENSATOR_NODE),
    'driver': ('driver.yaml', 'actuator_driver'),
    'analyze': ('recorder.yaml', 'analyze'),
}


@dataclass(frozen=True)
class Setup:
    """
    The configuration of offline runs, loaded once by the caller and passed down.

    Each mapping is one node's parameters (SI units): ``plant`` (simulated_actuator),
    ``controller`` (fuzzy_pid_controller), ``compensator`` (hysteresis_compensator),
    ``driver`` (actuator_driver), ``analyze`` (the metric settings); ``design`` is
    ``(omega_n_rad_s, alpha_m_per_v)`` of the design model; ``surface`` the fuzzy
    controller's :class:`~fiber_align.control.fuzzy_surface.FuzzySurface` (or None), built
    once with the setup because building it takes ~0.1 s.
    """

    plant: dict
    controller: dict
    compensator: dict
    driver: dict
    analyze: dict
    design: tuple
    surface: object


def load_setup(**files):
    """
    Read the params files of an offline run and the design model; return a :class:`Setup`.

    :param files: ``field=path`` to read another file for a field of :data:`SETUP_FILES`
        (``design=path`` for the actuator file, ``model=path`` for the generated model
        merged into ``compensator``).
    :raises ConfigError: a missing or broken file (named in the message).
    """
    kw = {k: load_params(files.get(k, f), node) for k, (f, node) in SETUP_FILES.items()}
    kw['compensator'].update(load_params(files.get('model', MODEL_FILE), COMPENSATOR_NODE))
    kw['design'] = design_dynamics(load_actuator(files.get('design', DESIGN_FILE)))
    kw['surface'] = surface_for(kw['controller'])
    return Setup(**kw)


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


def make_plant(plant, rate_hz, seed=0, noise=False, params=None, design=None):
    """
    Return a :class:`SimulatedActuator` of kind ``plant`` at ``rate_hz`` (Hz).

    :param noise: False sets the sensor noise to 0 (the resolution stays).
    :param params: the ``simulated_actuator`` parameters (None: read ``plant.yaml``).
    :param design: ``(omega_n_rad_s, alpha_m_per_v)`` of the design model (None: read
        ``actuator.yaml``).
    """
    if plant not in PLANTS:
        raise ValueError('unknown plant %r (allowed: %s)' % (plant, ', '.join(PLANTS)))
    p = dict(load_params(*SETUP_FILES['plant']) if params is None else params)
    p['hysteresis'] = plant
    p['seed'] = int(seed)
    if not noise:
        p['noise_rms_m'] = 0.0
    return SimulatedActuator.from_params(p, period_s=1.0 / float(rate_hz), dynamics=design)


def hysteresis_experiment(plant='default', seed=0, noise=True, rate_hz=IDENTIFY_RATE_HZ,
                          peak_v=None, setup=None):
    """
    Run the open-loop 0.1 Hz triangle on a plant; return ``(t, u, y_meas)`` (s, V, m).

    :param peak_v: top of the triangle (V); None is the paper's 72 V
        (scenario ``hysteresis-experiment``).
    :param setup: the loaded :class:`Setup` (None: read the files).
    """
    setup = load_setup() if setup is None else setup
    if peak_v is None:
        res = run('hysteresis-experiment', 'open-loop', rate_hz=rate_hz, seed=seed,
                  noise=noise, plant=plant, model=None, setup=setup)
        return res.t, res.v, res.y_meas
    p = make_plant(plant, rate_hz, seed, noise, setup.plant, setup.design)
    n = int(round(IDENTIFY_DURATION_S * rate_hz))
    t = np.arange(n) / float(rate_hz)
    u = [float(peak_v) * scen.triangle_wave(scen.HYST_HZ * tk) for tk in t.tolist()]
    y = [p.reset()]
    step = p.step
    for uk in u[:-1]:
        y.append(step(uk))
    return t, np.array(u), np.array(y)


def identified_model(plant='default', seed=0, noise=True, peak_v=None, n_operators=10,
                     setup=None):
    """
    Return the PI model identified (lsq) from the plant's hysteresis experiment.

    The experiment (:func:`hysteresis_experiment`, 0.1 Hz triangle up to ``peak_v``, V)
    runs at 1 kHz for one 10 s period with the plant's sensor (noise on by default, as
    a measurement would be); thresholds by the identification's rule
    ``r_i = i / n max(u)``. Nothing is cached: the identification takes tens of ms.
    """
    t, u, y = hysteresis_experiment(plant, seed, noise, peak_v=peak_v, setup=setup)
    return identify(t, u, y, method='lsq', n_operators=int(n_operators)).model


def compensator_model(comp):
    """
    Return the PI model of the compensator parameters: ``model_file``, else inline.

    :param comp: the ``hysteresis_compensator`` parameters.
    """
    path = str(comp['model_file'])
    if path:
        return PIModel.load(path)
    return PIModel.from_params(comp)


def default_model(plant, setup):
    """
    Return the feedforward model used when none is given (see the module docstring).

    The compensator's model when its ``model_plant`` is ``plant``; otherwise the model
    identified from ``plant``'s experiment with the same settings
    (:func:`compensator_identified_model`).
    """
    if str(setup.compensator['model_plant']) == plant:
        return compensator_model(setup.compensator)
    return compensator_identified_model(plant, setup)


def identification_settings(comp):
    """
    Return ``(peak_v, n_operators)`` of the compensator's identification experiment.

    From ``identification_peak_v`` (V; null: the paper's 72 V) and
    ``identification_operators`` of the compensator parameters.
    """
    v = comp['identification_peak_v']
    return (None if v is None else float(v)), int(comp['identification_operators'])


def compensator_identified_model(plant, setup):
    """Return the model identified on ``plant`` with the compensator's settings."""
    peak, n_ops = identification_settings(setup.compensator)
    return identified_model(plant, seed=0, noise=True, peak_v=peak, n_operators=n_ops,
                            setup=setup)


def resolve_model(model, plant, setup):
    """Resolve ``model`` (PIModel, params file, ``'identify'`` or None) to a PIModel."""
    if isinstance(model, PIModel):
        return model
    if model is None:
        return default_model(plant, setup)
    if model in ('identify', 'identified'):
        return compensator_identified_model(plant, setup)
    return PIModel.load(model)


def build_loop_parts(controller, rate_hz, setup, model=None, plant='default'):
    """
    Return ``(compensator, feedback)`` of a controller, built by the control factory.

    :param model: as in :func:`resolve_model`; resolved only for the controllers that
        invert a model (:data:`fiber_align.control.factory.MODEL_CONTROLLERS`).
    """
    pi = resolve_model(model, plant, setup) if controller in MODEL_CONTROLLERS else None
    comp = build_feedforward(controller, setup.compensator, pi, setup.design, rate_hz)
    fb = build_controller(controller, setup.controller, setup.compensator, setup.design,
                          rate_hz, setup.surface)
    return comp, fb


def run(scenario, controller, rate_hz=None, duration_s=None, seed=0, noise=False,
        plant='default', model=None, plant_obj=None, controller_params=None,
        comp_params=None, driver_params=None, reference_scale=1.0, analyze_params=None,
        setup=None):
    """
    Simulate one scenario with one controller; return a :class:`SimResult`.

    :param scenario: a name in :data:`fiber_align.simulation.scenarios.NAMES`.
    :param controller: a name in :data:`fiber_align.control.factory.CONTROLLERS`.
    :param rate_hz: control rate (Hz); default ``rate_hz`` of the controller parameters.
    :param duration_s: run length (s); default the scenario's.
    :param seed: seed of the plant's sensor noise.
    :param noise: sensor noise on (the plant.yaml value) or off.
    :param plant: plant kind (``default`` = dense-pi truth, ``paper``, ``linear``, ...).
    :param model: feedforward PI model: a PIModel, a params file, ``'identify'``, or
        None for :func:`default_model` (the compensator's model on its plant).
    :param plant_obj: a ready plant (overrides ``plant``, ``seed``, ``noise``).
    :param reference_scale: multiplies the reference (to test unreachable targets).
    :param setup: the loaded configuration (:func:`load_setup`; None reads the files);
        ``controller_params``, ``comp_params``, ``driver_params`` and ``analyze_params``
        replace one of its mappings.
    """
    sc = scen.make(scenario)
    setup = load_setup() if setup is None else setup
    over = {k: v for k, v in (('controller', controller_params), ('compensator', comp_params),
                              ('driver', driver_params), ('analyze', analyze_params))
            if v is not None}
    if over:
        setup = Setup(**dict(setup.__dict__, **over))
    rate = float(setup.plant['rate_hz'] if rate_hz is None else rate_hz)
    if not rate > 0:
        raise ValueError('rate must be > 0 Hz, got %g' % rate)
    dur = sc.duration_s if duration_s is None else float(duration_s)
    if not dur > 0:
        raise ValueError('duration must be > 0 s, got %g' % dur)
    n = int(round(dur * rate))
    period = 1.0 / rate
    p = plant_obj if plant_obj is not None else make_plant(plant, rate, seed, noise,
                                                           setup.plant, setup.design)
    drv = DriverCore.from_params(setup.driver, ramp_period_s=period)
    reach = p.reachable_m()
    if sc.open_loop:
        loop = _run_open_loop(sc, n, period, p, drv)
        clamped = held = 0
    else:
        comp, fbc = build_loop_parts(controller, rate, setup, model, plant)
        loop = _run_closed_loop(sc, n, period, p, drv, comp, fbc, reach, reference_scale)
        clamped, held = loop[-2:]
    t = np.arange(n) * period
    r, ym, yt, v, ffa, fba = (np.array(a, dtype=float) for a in loop[:6])
    gains = (np.fromiter(itertools.chain.from_iterable(loop[6]), float, 3 * n)
             if loop[6] else np.zeros(3 * n))
    res = SimResult(scenario, controller, rate, t, r, ym, yt, v, ffa, fba,
                    gains.reshape(n, 3))
    res.metrics = metrics(res, sc, (p.v_min, p.v_max), setup.analyze)
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

    The periods are :meth:`fiber_align.simulation.loop.ClosedLoop.run` (the one loop
    body); this records what each period measured and commanded.
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
    rec = {'y': [], 'x': [], 'v': [], 'ff': [], 'fb': [], 'gains': []}
    nan0 = fbc.nan_count if fbc is not None else 0
    ClosedLoop(p, drv, comp, fbc, period).run(rs, rec)
    held = fbc.nan_count - nan0 if fbc is not None else 0   # periods held (NaN error)
    return (rs, rec['y'], rec['x'], rec['v'], rec['ff'], rec['fb'], rec['gains'], clamped,
            held)


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


def metrics(res, sc, v_limits, params):
    """
    Return the metrics dict of a run (SI keys; keys that do not apply are None).

    All from :func:`fiber_align.simulation.metrics.loop_metrics` with the ``analyze``
    settings (``step_min_m``, ``settling_band``, ``settling_noise_sigmas``; default
    ``config/recorder.yaml``) and the tracking window :func:`tracking_skip_s`:

    * on the measured displacement (what the graph publishes, so a lockstep bag gives
      the same numbers): ``settling_time_s``, ``overshoot_pct``, ``rise_time_s`` (the
      worst over the setpoint steps), ``rms_error_m``, ``max_error_m``, ``steps`` (one
      dict per step), ``max_voltage_v``, ``saturation``, ``tracking_skip_s``;
    * on the true tip position: ``true_`` + the same scalar keys.
    """
    kw = step_settings(params)
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
        out.update({prefix + k: v for k, v in run_scores(lm).items()})
        if not prefix:
            out['steps'] = lm.get('steps', [])
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
