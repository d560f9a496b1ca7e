# SPDX-License-Identifier: Apache-2.0
"""
Optical coupling between two single-mode fibers and the power detector (pure numpy).

The input fiber rides on the actuator tip (displacement ``x``, m); the output fiber's core
sits at the slot position ``s(t)`` (m), unknown to the sequencer. With equal mode-field
radius ``w`` (m), lateral offset ``d = x - s`` (m) and gap ``z`` (m), the power coupling
efficiency of two Gaussian modes is::

    eta = exp(-(d / w)^2 / (1 + Z^2)) / (1 + Z^2),   Z = lambda z / (2 pi n w^2)

and the coupled power is ``P = P_source * eta`` (W). ``ln P`` is exactly quadratic in
``x``, which the sequencer's peak search exploits.

The detector adds a noise floor (RMS of the dark reading, W), relative intensity noise
(standard deviation in dB of a lit reading), a first-order averaging low-pass (time
constant, s) and saturation (W). All noise is per raw sample, before averaging.

Defaults live in ``config/optics.yaml`` under node ``simulated_actuator``, nested under
``optics`` (ROS names ``optics.*``), so the simulated actuator node can take this file as
a second ``--params-file`` next to its own.
"""

import math

import numpy as np

from fiber_align.config import load_params

CONFIG_FILE = 'optics.yaml'
CONFIG_NODE = 'simulated_actuator'
CONFIG_KEY = 'optics'
DBM_FLOOR_W = 1e-15   # W; power values below this are shown as -120 dBm


def w_to_dbm(p_w):
    """Convert power in W to dBm (for people); values <= 1e-15 W map to -120 dBm."""
    p = np.maximum(np.asarray(p_w, dtype=float), DBM_FLOOR_W)
    out = 10.0 * np.log10(p / 1e-3)
    return float(out) if out.ndim == 0 else out


def dbm_to_w(p_dbm):
    """Convert dBm to W."""
    out = 1e-3 * 10.0 ** (np.asarray(p_dbm, dtype=float) / 10.0)
    return float(out) if out.ndim == 0 else out


def loss_db(p_w, p_ref_w):
    """Return the loss ``10 log10(p_ref / p)`` in dB (>= 0 when ``p <= p_ref``)."""
    p = np.maximum(np.asarray(p_w, dtype=float), DBM_FLOOR_W)
    out = 10.0 * np.log10(np.maximum(p_ref_w, DBM_FLOOR_W) / p)
    return float(out) if out.ndim == 0 else out


def rayleigh_factor(gap_m, mode_radius_m, wavelength_m, index=1.0):
    """Return ``1 + Z^2`` with ``Z = lambda z / (2 pi n w^2)`` (dimensionless)."""
    z_norm = wavelength_m * gap_m / (2.0 * math.pi * index * mode_radius_m ** 2)
    return 1.0 + z_norm ** 2


def coupling_efficiency(offset_m, gap_m=0.0, mode_radius_m=5.2e-6, wavelength_m=1.55e-6,
                        index=1.0):
    """
    Return the power coupling efficiency of two equal single-mode fibers (0..1).

    :param offset_m: lateral offset ``d`` between the cores (m), scalar or array.
    :param gap_m: axial gap ``z`` between the end faces (m).
    :param mode_radius_m: mode-field radius ``w`` (m), 5.2 um for SMF-28 at 1550 nm.
    :param wavelength_m: vacuum wavelength (m).
    :param index: refractive index of the gap medium.
    """
    q = rayleigh_factor(gap_m, mode_radius_m, wavelength_m, index)
    d = np.asarray(offset_m, dtype=float)
    out = np.exp(-(d / mode_radius_m) ** 2 / q) / q
    return float(out) if out.ndim == 0 else out


def _section(params, name):
    """Return ``params[name]`` as a flat mapping (accepts nested or ROS dotted names)."""
    if isinstance(params.get(name), dict):
        return dict(params[name])
    prefix = name + '.'
    sub = {k[len(prefix):]: v for k, v in params.items() if k.startswith(prefix)}
    return sub if sub else dict(params)


class FiberCoupling:
    """
    Noise-free coupled power as a function of time and actuator displacement.

    The slot (output core) position is ``slot_position_m + slot_drift_m_per_s * t +
    slot_vibration_amplitude_m * sin(2 pi slot_vibration_frequency_hz t)`` (m).
    """

    def __init__(self, source_power_w=1e-3, wavelength_m=1.55e-6, mode_radius_m=5.2e-6,
                 gap_m=10e-6, index=1.0, slot_position_m=40e-6, slot_drift_m_per_s=0.0,
                 slot_vibration_amplitude_m=0.0, slot_vibration_frequency_hz=0.0,
                 fiber_broken=False):
        """Store the link parameters (SI: W, m, m/s, Hz)."""
        if mode_radius_m <= 0 or wavelength_m <= 0 or index <= 0:
            raise ValueError('mode_radius_m, wavelength_m and index must be > 0')
        if source_power_w < 0 or gap_m < 0:
            raise ValueError('source_power_w and gap_m must be >= 0')
        self.source_power_w = float(source_power_w)
        self.wavelength_m = float(wavelength_m)
        self.mode_radius_m = float(mode_radius_m)
        self.gap_m = float(gap_m)
        self.index = float(index)
        self.slot_position_m = float(slot_position_m)
        self.slot_drift_m_per_s = float(slot_drift_m_per_s)
        self.slot_vibration_amplitude_m = float(slot_vibration_amplitude_m)
        self.slot_vibration_frequency_hz = float(slot_vibration_frequency_hz)
        self.fiber_broken = bool(fiber_broken)

    def slot_position(self, t_s):
        """Return the output core position (m) at time ``t_s`` (s); scalar or array."""
        t = np.asarray(t_s, dtype=float)
        s = self.slot_position_m + self.slot_drift_m_per_s * t
        if self.slot_vibration_amplitude_m:
            s = s + self.slot_vibration_amplitude_m * np.sin(
                2.0 * math.pi * self.slot_vibration_frequency_hz * t)
        return float(s) if s.ndim == 0 else s

    def max_power_w(self):
        """Return the largest coupled power (W), reached at zero offset."""
        if self.fiber_broken:
            return 0.0
        return self.source_power_w * coupling_efficiency(
            0.0, self.gap_m, self.mode_radius_m, self.wavelength_m, self.index)

    def power_w(self, t_s, x_m):
        """Return the true coupled power (W) with the input core at ``x_m`` (m) at ``t_s``."""
        if isinstance(x_m, (float, int)) and isinstance(t_s, (float, int)):
            return self._power_scalar(float(t_s), float(x_m))
        x = np.asarray(x_m, dtype=float)
        if self.fiber_broken:
            out = np.zeros_like(x)
        else:
            out = self.source_power_w * np.asarray(coupling_efficiency(
                x - self.slot_position(t_s), self.gap_m, self.mode_radius_m,
                self.wavelength_m, self.index))
        return float(out) if out.ndim == 0 else out

    def loss_db(self, t_s, x_m):
        """Return the loss (dB) against the true maximum with the core at ``x_m`` (m)."""
        return loss_db(self.power_w(t_s, x_m), self.max_power_w())

    def _power_scalar(self, t, x):
        """:meth:`power_w` of floats (s, m), the per-period call, in scalar math."""
        if self.fiber_broken:
            return 0.0
        s = self.slot_position_m + self.slot_drift_m_per_s * t
        if self.slot_vibration_amplitude_m:
            s += self.slot_vibration_amplitude_m * math.sin(
                2.0 * math.pi * self.slot_vibration_frequency_hz * t)
        q = rayleigh_factor(self.gap_m, self.mode_radius_m, self.wavelength_m, self.index)
        return self.source_power_w * (math.exp(-((x - s) / self.mode_radius_m) ** 2 / q) / q)


class Detector:
    """Photodetector: noise floor, relative intensity noise, averaging low-pass, saturation."""

    def __init__(self, noise_floor_w=1e-10, rin_db=0.02, averaging_time_s=0.5e-3,
                 saturation_w=10e-3, sample_period_s=1e-3, seed=0, floor_w=0.0,
                 quantum_w=0.0):
        """
        Set the detector up.

        :param noise_floor_w: RMS of the dark reading per raw sample (W); -70 dBm = 1e-10 W.
        :param rin_db: standard deviation of a lit raw reading (dB).
        :param averaging_time_s: time constant of the first-order averaging (s); 0 = none.
        :param saturation_w: largest reading (W).
        :param sample_period_s: default time between readings (s).
        :param seed: seed of the noise generator.
        :param floor_w: the meter's clamp (W): a reading below it reads as it (a meter
            that reports a constant floor in the dark); 0 = none.
        :param quantum_w: the meter's resolution (W): readings are rounded down to a
            multiple of it (a quantised reading); 0 = none.
        """
        if min(noise_floor_w, rin_db, averaging_time_s, floor_w, quantum_w) < 0 or \
                saturation_w <= 0:
            raise ValueError('detector noise, averaging, floor, quantum and saturation must '
                             'be >= 0 (> 0 for saturation_w)')
        self.noise_floor_w = float(noise_floor_w)
        self.rin_db = float(rin_db)
        self.averaging_time_s = float(averaging_time_s)
        self.saturation_w = float(saturation_w)
        self.sample_period_s = float(sample_period_s)
        self.floor_w, self.quantum_w = float(floor_w), float(quantum_w)
        self.rng = np.random.default_rng(seed)
        self._state = None

    def reset(self, seed=None):
        """Forget the averaging state; reseed the noise if ``seed`` is given."""
        self._state = None
        if seed is not None:
            self.rng = np.random.default_rng(seed)

    def lag_s(self, dt_s=None):
        """Return the delay (s) the averaging adds to a ramp at sample period ``dt_s``."""
        dt = self.sample_period_s if dt_s is None else dt_s
        if self.averaging_time_s <= 0:
            return 0.0
        a = 1.0 - math.exp(-dt / self.averaging_time_s)
        return dt * (1.0 - a) / a

    def measure(self, p_true_w, dt_s=None):
        """Return one reading (W) of the true power ``p_true_w`` (W), ``dt_s`` after the last."""
        dt = self.sample_period_s if dt_s is None else float(dt_s)
        gain = 10.0 ** (self.rin_db * self.rng.standard_normal() / 10.0)
        raw = abs(float(p_true_w) * gain + self.noise_floor_w * self.rng.standard_normal())
        if self._state is None or self.averaging_time_s <= 0:
            self._state = raw
        else:
            a = 1.0 - math.exp(-dt / self.averaging_time_s)
            self._state += a * (raw - self._state)
        return self.meter_reading(min(self._state, self.saturation_w))

    def meter_reading(self, p_w):
        """Return what the meter shows of ``p_w`` (W): quantised, clamped at ``floor_w``."""
        if self.quantum_w > 0:
            p_w = math.floor(p_w / self.quantum_w) * self.quantum_w
        return max(p_w, self.floor_w)

    def measure_array(self, p_true_w, dt_s=None):
        """Return readings (W) for an array of true powers sampled every ``dt_s`` (s)."""
        p = np.asarray(p_true_w, dtype=float)
        return np.array([self.measure(v, dt_s) for v in p.ravel()]).reshape(p.shape)


class OpticalLink:
    """Coupling plus detector: what the simulated actuator publishes as ``optical_power``."""

    def __init__(self, coupling, detector):
        """Combine a :class:`FiberCoupling` and a :class:`Detector`."""
        self.coupling = coupling
        self.detector = detector

    @classmethod
    def from_params(cls, params=None, seed=0, **overrides):
        """
        Build a link from an ``optics`` parameter mapping; ``overrides`` replace keys.

        :param params: mapping with the keys of ``config/optics.yaml`` (nested under
            ``optics`` or flat, or ROS dotted ``optics.*``); ``None`` loads the file.
        :param seed: detector noise seed.
        """
        if params is None:
            params = load_params(CONFIG_FILE, CONFIG_NODE)
        p = _section(params, CONFIG_KEY)
        p.update(overrides)
        known_c = ('source_power_w', 'wavelength_m', 'mode_radius_m', 'gap_m', 'index',
                   'slot_position_m', 'slot_drift_m_per_s', 'slot_vibration_amplitude_m',
                   'slot_vibration_frequency_hz', 'fiber_broken')
        known_d = ('noise_floor_w', 'rin_db', 'averaging_time_s', 'saturation_w',
                   'sample_period_s', 'floor_w', 'quantum_w')
        unknown = sorted(set(p) - set(known_c) - set(known_d))
        if unknown:
            raise ValueError('unknown optics parameter(s): %s (known: %s)'
                             % (', '.join(unknown), ', '.join(known_c + known_d)))
        coupling = FiberCoupling(**{k: p[k] for k in known_c if k in p})
        detector = Detector(seed=seed, **{k: p[k] for k in known_d if k in p})
        return cls(coupling, detector)

    def measure(self, t_s, x_m, dt_s=None):
        """Return the detector reading (W) at time ``t_s`` (s) with the core at ``x_m`` (m)."""
        return self.detector.measure(self.coupling.power_w(t_s, x_m), dt_s)

    def loss_db(self, t_s, x_m):
        """Return the true loss (dB) against the (moving) maximum at ``t_s``, ``x_m``."""
        return self.coupling.loss_db(t_s, x_m)


def load_optics(path=CONFIG_FILE, seed=0, **overrides):
    """Load :class:`OpticalLink` defaults from a params file; ``overrides`` replace keys."""
    return OpticalLink.from_params(load_params(path, CONFIG_NODE), seed=seed, **overrides)
