# SPDX-License-Identifier: Apache-2.0
"""
Build the control objects of a controller name from parameter mappings: the one factory.

The ROS nodes, the offline loop (:mod:`fiber_align.simulation.simulate`) and the tests
all call these functions, so the graph and ``fiber-align simulate`` run the same objects.
Nothing here reads a file: the caller passes the parameters (``config/controller.yaml``
node ``fuzzy_pid_controller``, ``config/compensator.yaml`` node
``hysteresis_compensator``), an already loaded PI model and the design model's mode
``(omega_n_rad_s, alpha_m_per_v)`` (:func:`fiber_align.design.mode.design_dynamics`).

Controllers (:data:`CONTROLLERS`): ``open-loop`` (r times a linear gain, V/m),
``feedforward`` (inverse PI of a shaped reference), ``pid`` (tuned plain PID), ``fuzzy``
(fuzzy PID), ``composite`` (inverse PI + fuzzy PID, paper Figure 21), ``composite-pid``
(inverse PI + plain PID).
"""

import math

from fiber_align.control.feedforward import Feedforward
from fiber_align.control.fuzzy_pid import FuzzyPid, make_pid, PlainPid
from fiber_align.control.shaping import design, Lead, ReferenceModel, Shaper, shaper_delay_s

#: The control laws (``fiber-align simulate --controller``, the graph's ``controller``): the
#: one list, imported wherever they are offered or checked.
CONTROLLERS = ('open-loop', 'feedforward', 'pid', 'fuzzy', 'composite', 'composite-pid')
#: The controllers without a feedback law (the compensator drives alone).
FEEDFORWARD_ONLY = ('open-loop', 'feedforward')
# The controllers whose compensator inverts a PI model (the others need no model).
MODEL_CONTROLLERS = ('feedforward', 'composite', 'composite-pid')


def check_controller(controller):
    """Raise ValueError unless ``controller`` is a name in :data:`CONTROLLERS`."""
    if controller not in CONTROLLERS:
        raise ValueError('unknown controller %r (allowed: %s)'
                         % (controller, ', '.join(CONTROLLERS)))


def shaping_mode(comp, design_dynamics):
    """
    Return ``(omega_n_rad_s, damping_ratio)`` that the shaping is designed for.

    ``shaping_omega_n_rad_s`` of ``comp`` (rad/s), or when it is <= 0 the design model's
    first mode ``design_dynamics[0]``; ``shaping_damping_ratio`` (dimensionless).
    """
    wn = float(comp['shaping_omega_n_rad_s'])
    if wn <= 0:
        wn = float(design_dynamics[0])
    return wn, float(comp['shaping_damping_ratio'])


def build_shaper(comp, design_dynamics, rate_hz):
    """
    Return the reference :class:`~fiber_align.control.shaping.Shaper` of ``comp``, or None.

    :param comp: compensator parameters (``shaping``, ``shaping_omega_n_rad_s``,
        ``shaping_damping_ratio``).
    :param design_dynamics: ``(omega_n_rad_s, alpha_m_per_v)`` of the design model.
    :param rate_hz: control rate (Hz).
    """
    kind = str(comp['shaping'])
    if kind == 'none':
        return None
    wn, zeta = shaping_mode(comp, design_dynamics)
    return Shaper(design(kind, wn, zeta, 1.0 / float(rate_hz)))


def build_lead(comp, rate_hz, shaper):
    """
    Return the :class:`~fiber_align.control.shaping.Lead` of ``comp``, or None.

    Its horizon is the shaper's mean delay plus one period (s); ``delay_compensation``
    off gives None.
    """
    if not bool(comp['delay_compensation']):
        return None
    period = 1.0 / float(rate_hz)
    return Lead(period, shaper_delay_s(shaper, period) + period,
                float(comp['delay_compensation_max_accel_m_per_s2']))


def build_reference_model(comp, design_dynamics, rate_hz):
    """Return the composite feedback's :class:`~fiber_align.control.shaping.ReferenceModel`."""
    wn, zeta = shaping_mode(comp, design_dynamics)
    shaper = build_shaper(comp, design_dynamics, rate_hz)
    return ReferenceModel(shaper, wn, zeta, 1.0 / float(rate_hz),
                          lead=build_lead(comp, rate_hz, shaper))


def build_feedforward(controller, comp, model, design_dynamics, rate_hz):
    """
    Return the compensator (``step(r m) -> V``) of a controller.

    :param controller: a name in :data:`CONTROLLERS`.
    :param comp: compensator parameters (``config/compensator.yaml``).
    :param model: the loaded :class:`~fiber_align.hysteresis.pi.PIModel` to invert; used
        by the controllers in :data:`MODEL_CONTROLLERS` only (may be None for the others).
    :param design_dynamics: ``(omega_n_rad_s, alpha_m_per_v)`` of the design model.
    :param rate_hz: control rate (Hz).
    """
    check_controller(controller)
    if controller == 'open-loop':
        return Feedforward(gain_v_per_m=float(comp['open_loop_gain_v_per_m']))
    if controller not in MODEL_CONTROLLERS:
        return Feedforward(gain_v_per_m=0.0)
    if model is None:
        raise ValueError('controller %s needs a PI model' % controller)
    shaper = build_shaper(comp, design_dynamics, rate_hz)
    return Feedforward(model, shaper=shaper, lead=build_lead(comp, rate_hz, shaper))


def build_controller(controller, params, comp, design_dynamics, rate_hz, surface=None):
    """
    Return the feedback law (``step(r m, y m) -> V``) of a controller, or None.

    :param controller: a name in :data:`CONTROLLERS`; ``open-loop`` and ``feedforward``
        have no feedback (None).
    :param params: controller parameters (``config/controller.yaml``, nested).
    :param comp: compensator parameters (the composite feedback follows the model of the
        shaped reference, :func:`build_reference_model`).
    :param design_dynamics: ``(omega_n_rad_s, alpha_m_per_v)`` of the design model.
    :param rate_hz: control rate (Hz).
    :param surface: a :class:`~fiber_align.control.fuzzy_surface.FuzzySurface` built before
        (:func:`~fiber_align.control.fuzzy_pid.surface_for`), reused when it fits
        ``params``.
    """
    check_controller(controller)
    if controller in FEEDFORWARD_ONLY:
        return None
    refm = None
    if controller.startswith('composite') and \
            str(params['composite_feedback_reference']) == 'model':
        refm = build_reference_model(comp, design_dynamics, rate_hz)
    if controller in ('pid', 'composite-pid'):
        return PlainPid(make_pid(params, rate_hz), refm)
    return FuzzyPid.from_params(params, rate_hz, reference_filter=refm, surface=surface)


#: Allowed values of the controller parameters by the last part of their name: (lo, hi)
#: for every value, SI.
#: kp may be negative (the tuned 1 kHz loop uses kp = -0.1 / alpha, docs/control.md);
#: ki and kd may not (a negative integral or derivative gain destabilises the loop).
PARAM_RANGES = {
    'kp0': (-1e12, 1e12), 'ki0': (0.0, 1e15), 'kd0': (0.0, 1e9),
    'kp': (-1e12, 1e12), 'ki': (0.0, 1e15), 'kd': (0.0, 1e9),
    'kp_unit': (0.0, 1e12), 'ki_unit': (0.0, 1e15), 'kd_unit': (0.0, 1e9),
    'e_scale_per_m': (1e-3, 1e12), 'ec_scale_s_per_m': (1e-6, 1e9),
    'output_scale': (0.0, 10.0), 'derivative_filter_hz': (0.0, 1e6),
    'u_min': (-1000.0, 1000.0), 'u_max': (-1000.0, 1000.0), 'tracking_time_s': (0.0, 10.0),
    'gain_rates_hz': (1.0, 1e6),
}


def check_param(name, value):
    """Return ``None`` or the reason why ``value`` is not allowed for parameter ``name``."""
    key = name.split('.')[-1]
    if key not in PARAM_RANGES:
        return None
    lo, hi = PARAM_RANGES[key]
    vals = list(value) if isinstance(value, (list, tuple)) or hasattr(value, 'tolist') \
        else [value]
    for v in vals:
        try:
            f = float(v)
        except (TypeError, ValueError):
            return '%s=%r is not a number' % (name, v)
        if not (math.isfinite(f) and lo <= f <= hi):
            return '%s=%r is out of range [%g, %g]' % (name, v, lo, hi)
    return None
