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
"""

from dataclasses import dataclass, field
import math

import numpy as np

from fiber_align.analysis.metrics import step_metrics, tracking_metrics
from fiber_align.config import ConfigError, load_params
from fiber_align.control import scenarios as scen
from fiber_align.control.driver import DriverCore
from fiber_align.control.feedforward import Feedforward
from fiber_align.control.fuzzy_pid import FuzzyPid, make_pid, PlainPid
from fiber_align.control.shaping import design, Lead, ReferenceModel, Shaper, shaper_delay_s
from fiber_align.hysteresis.pi import PIModel
from fiber_align.plant.actuator import design_dynamics, SimulatedActuator

CONTROLLERS = ('open-loop', 'feedforward', 'pid', 'fuzzy', 'composite', 'composite-pid')
PLANTS = ('default', 'paper', 'linear', 'dense-pi', 'bouc-wen')
COMPENSATOR_FILE = 'compensator.yaml'
COMPENSATOR_NODE = 'hysteresis_compensator'
IDENTIFY_RATE_HZ = 1000.0
_MODEL_CACHE = {}


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


def compensator_params(path=COMPENSATOR_FILE):
    """Return the ``hysteresis_compensator`` parameters (shaping, gain, model)."""
    return load_params(path, COMPENSATOR_NODE)


def make_plant(plant, rate_hz, seed=0, noise=False, params=None):
    """
    Return a :class:`SimulatedActuator` of kind ``plant`` at ``rate_hz`` from plant.yaml.

    :param noise: False sets the sensor noise to 0 (the resolution stays).
    """
    if plant not in PLANTS:
        raise ValueError('unknown plant %r (allowed: %s)' % (plant, ', '.join(PLANTS)))
    p = dict(load_params('plant.yaml', 'simulated_actuator') if params is None else params)
    p['hysteresis'] = plant
    p['seed'] = int(seed)
    if not noise:
        p['noise_rms_m'] = 0.0
    return SimulatedActuator.from_params(p, period_s=1.0 / float(rate_hz))


def hysteresis_experiment(plant='default', seed=0, noise=True, rate_hz=IDENTIFY_RATE_HZ):
    """Run the open-loop 0-72 V, 0.1 Hz triangle on a plant; return ``(t, u, y_meas)``."""
    res = run('hysteresis-experiment', 'open-loop', rate_hz=rate_hz, seed=seed, noise=noise,
              plant=plant, model=None)
    return res.t, res.v, res.y_meas


def identified_model(plant='default', seed=0, noise=True):
    """
    Return the PI model identified (lsq, 10 operators) from the plant's experiment.

    The experiment runs at 1 kHz for one 10 s period with the plant's sensor; results are
    cached per (plant, seed, noise).
    """
    key = (plant, int(seed), bool(noise))
    if key not in _MODEL_CACHE:
        from fiber_align.hysteresis.identify import identify
        t, u, y = hysteresis_experiment(plant, seed, noise)
        _MODEL_CACHE[key] = identify(t, u, y, method='lsq', n_operators=10).model
    return _MODEL_CACHE[key]


def _load_model(model, plant, seed, noise):
    """Resolve ``model`` (PIModel, path, ``'identify'`` or None) to a PIModel."""
    if isinstance(model, PIModel):
        return model
    if model in (None, 'identify', 'identified'):
        return identified_model(plant, seed, noise)
    return PIModel.load(model)


def make_shaper(comp, rate_hz, plant_obj):
    """Return the reference :class:`Shaper` configured in ``comp`` (or None)."""
    kind = str(comp.get('shaping', 'none'))
    if kind == 'none':
        return None
    wn = float(comp.get('shaping_omega_n_rad_s', 0.0))
    if wn <= 0:
        wn = design_dynamics()[0]
    zeta = float(comp.get('shaping_damping_ratio', 0.03))
    return Shaper(design(kind, wn, zeta, 1.0 / float(rate_hz)))


def build(controller, rate_hz, plant_obj, model=None, plant='default', seed=0, noise=False,
          controller_params=None, comp_params=None):
    """
    Return ``(compensator, feedback)`` objects for a controller name.

    The compensator has ``step(r) -> V``; the feedback has ``step(r, y) -> V``
    (or is None for open-loop controllers).
    """
    if controller not in CONTROLLERS:
        raise ValueError('unknown controller %r (allowed: %s)'
                         % (controller, ', '.join(CONTROLLERS)))
    comp = compensator_params() if comp_params is None else comp_params
    ctl = (load_params('controller.yaml', 'fuzzy_pid_controller')
           if controller_params is None else controller_params)
    if controller == 'open-loop':
        return Feedforward(gain_v_per_m=float(comp['open_loop_gain_v_per_m'])), None
    if controller in ('feedforward', 'composite', 'composite-pid'):
        shaper = make_shaper(comp, rate_hz, plant_obj)
        ff = Feedforward(_load_model(model, plant, seed, noise), shaper=shaper,
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
        wn = design_dynamics()[0]
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
                float(comp.get('delay_compensation_max_rate_m_per_s', 0.01)))


def run(scenario, controller, rate_hz=None, duration_s=None, seed=0, noise=False,
        plant='default', model=None, plant_obj=None, controller_params=None,
        comp_params=None, driver_params=None, reference_scale=1.0):
    """
    Simulate one scenario with one controller; return a :class:`SimResult`.

    :param scenario: a name in :data:`fiber_align.control.scenarios.NAMES`.
    :param controller: a name in :data:`CONTROLLERS`.
    :param rate_hz: control rate (Hz); default ``rate_hz`` of config/controller.yaml.
    :param duration_s: run length (s); default the scenario's.
    :param seed: seed of the plant's sensor noise.
    :param noise: sensor noise on (the plant.yaml value) or off.
    :param plant: plant kind (``default`` = dense-pi truth, ``paper``, ``linear``, ...).
    :param model: feedforward PI model: a PIModel, a params file, or None to identify
        it from the ``hysteresis-experiment`` run on the same plant.
    :param plant_obj: a ready plant (overrides ``plant``, ``seed``, ``noise``).
    :param reference_scale: multiplies the reference (to test unreachable targets).
    """
    sc = scen.make(scenario)
    ctl_params = (load_params('controller.yaml', 'fuzzy_pid_controller')
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
    drv = DriverCore.from_params(load_params('driver.yaml', 'actuator_driver')
                                 if driver_params is None else driver_params)
    reach = p.reachable_m()
    if sc.open_loop:
        comp, fbc = None, None
    else:
        comp, fbc = build(controller, rate, p, model, plant, seed, noise, ctl_params,
                          comp_params)
    t = np.arange(n) * period
    r = np.zeros(n)
    ym = np.zeros(n)
    yt = np.zeros(n)
    v = np.zeros(n)
    ffa = np.zeros(n)
    fba = np.zeros(n)
    gains = np.zeros((n, 3))
    clamped = 0
    held = 0
    y = p.reset()
    for k in range(n):
        tk = k * period
        if sc.open_loop:
            rk = math.nan
            ff = sc.drive(tk)
            fb = 0.0
        else:
            rk = sc.reference(tk) * reference_scale
            if rk > reach:
                rk = reach
                clamped += 1
            elif rk < 0.0:
                rk = 0.0
                clamped += 1
            ff = comp.step(rk)
            if fbc is not None:
                fb = fbc.step(rk, y)
                held += fbc.held
                gains[k] = fbc.gains
            else:
                fb = 0.0
        vk = drv.command(ff, fb, tk)
        r[k] = rk
        ym[k] = y
        yt[k] = p.x
        v[k] = vk
        ffa[k] = ff
        fba[k] = fb
        y = p.step(vk)
    res = SimResult(scenario, controller, rate, t, r, ym, yt, v, ffa, fba, gains)
    res.metrics = metrics(res, sc, reach)
    res.metrics.update({
        'scenario': scenario, 'controller': controller if not sc.open_loop else 'open-loop',
        'plant': plant, 'rate_hz': rate, 'duration_s': n * period, 'seed': int(seed),
        'noise': bool(noise), 'reachable_m': reach, 'reference_clamped_samples': clamped,
        'measurement_held_samples': held, 'driver_saturation_count': drv.saturation_count,
        'driver_slew_count': drv.slew_count})
    return res


def metrics(res, sc, reach):
    """
    Return the metrics dict of a run (true displacement against the reference).

    Step: settling (2 % band), overshoot, 10-90 % rise, and tracking errors over the
    second half of the run. Sine and triangle: tracking errors after the first period.
    ``max_voltage_v`` always. Keys that do not apply are None.
    """
    out = {'settling_time_s': None, 'overshoot_pct': None, 'rise_time_s': None,
           'rms_error_m': None, 'max_error_m': None,
           'max_voltage_v': float(np.max(res.v)) if res.v.size else 0.0}
    if sc.open_loop or res.t.size < 2:
        return out
    if sc.name == 'step':
        out.update({k: val for k, val in step_metrics(res.t, res.y_true, res.r[-1]).items()
                    if k in ('settling_time_s', 'overshoot_pct', 'rise_time_s')})
        skip = 0.5 * (res.t[-1] - res.t[0])
    else:
        skip = sc.skip_s if res.t[-1] > sc.skip_s else 0.0
    out.update({k: val for k, val in tracking_metrics(res.t, res.r, res.y_true, skip).items()
                if k in ('rms_error_m', 'max_error_m')})
    for k, val in list(out.items()):
        if isinstance(val, float) and math.isinf(val):
            out[k] = None if k != 'settling_time_s' else val
    return out


def check_model_file(path):
    """Raise ConfigError unless ``path`` holds a PI model."""
    try:
        PIModel.load(path)
    except (OSError, ValueError) as exc:
        raise ConfigError('cannot load model %s: %s' % (path, exc)) from None
