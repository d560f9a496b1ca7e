# SPDX-License-Identifier: Apache-2.0
"""Tests of the optical coupling model and the detector (fiber_align.plant.optics)."""

import math

import numpy as np
import pytest

from fiber_align.plant import optics as op


def test_coupling_matches_gaussian_overlap_formula():
    w, lam, z = 5.2e-6, 1.55e-6, 10e-6
    zn = lam * z / (2 * math.pi * w * w)
    q = 1 + zn * zn
    d = np.array([0.0, 1e-6, w, 3e-6])
    expected = np.exp(-(d / w) ** 2 / q) / q
    got = op.coupling_efficiency(d, z, w, lam)
    assert np.allclose(got, expected, rtol=1e-12)
    # no gap: 1 at zero offset, 1/e at one mode radius
    assert op.coupling_efficiency(0.0) == pytest.approx(1.0)
    assert op.coupling_efficiency(w) == pytest.approx(math.exp(-1.0))
    # symmetric in the offset
    assert op.coupling_efficiency(-2e-6, z) == pytest.approx(op.coupling_efficiency(2e-6, z))


def test_005_db_offset_is_about_055_um_for_smf28():
    # loss(d) = 4.343 (d / w)^2 dB -> 0.05 dB at d = w sqrt(0.05 / 4.343)
    d = 5.2e-6 * math.sqrt(0.05 / (10 / math.log(10)))
    assert d == pytest.approx(0.558e-6, abs=0.005e-6)
    assert op.loss_db(op.coupling_efficiency(d), 1.0) == pytest.approx(0.05, rel=1e-9)


def test_dbm_conversions_round_trip():
    assert op.w_to_dbm(1e-3) == pytest.approx(0.0)
    assert op.w_to_dbm(1e-10) == pytest.approx(-70.0)
    assert op.dbm_to_w(-70.0) == pytest.approx(1e-10)
    assert op.w_to_dbm(0.0) == pytest.approx(-120.0)


def test_config_defaults_and_true_power():
    link = op.load_optics()
    c = link.coupling
    assert c.source_power_w == pytest.approx(1e-3)
    assert c.mode_radius_m == pytest.approx(5.2e-6)
    assert c.wavelength_m == pytest.approx(1550e-9)
    assert link.detector.noise_floor_w == pytest.approx(1e-10)
    # maximum at the slot, 0.036 dB gap loss with the 10 um default gap
    assert op.loss_db(c.max_power_w(), 1e-3) == pytest.approx(0.036, abs=0.001)
    assert c.power_w(0.0, c.slot_position_m) == pytest.approx(c.max_power_w())
    assert c.loss_db(0.0, c.slot_position_m + 1e-6) > 0.1


def test_dotted_ros_names_as_the_node_passes_them():
    flat = {'optics.source_power_w': 2e-3, 'optics.slot_position_m': 10e-6,
            'optics.noise_floor_w': 1e-9}
    link = op.OpticalLink.from_params(flat, seed=1)
    assert link.coupling.source_power_w == pytest.approx(2e-3)
    assert link.coupling.slot_position_m == pytest.approx(10e-6)
    assert link.detector.noise_floor_w == pytest.approx(1e-9)
    with pytest.raises(ValueError, match='unknown optics parameter'):
        op.OpticalLink.from_params({'optics.bogus_m': 1.0})


def test_slot_drift_and_vibration_move_the_maximum():
    c = op.FiberCoupling(slot_position_m=10e-6, slot_drift_m_per_s=1e-6,
                         slot_vibration_amplitude_m=0.2e-6, slot_vibration_frequency_hz=50.0)
    assert c.slot_position(2.0) == pytest.approx(12e-6)
    assert c.slot_position(0.005) == pytest.approx(10.005e-6 + 0.2e-6)
    assert c.power_w(2.0, 12e-6) == pytest.approx(c.max_power_w())


def test_broken_fiber_gives_no_light():
    c = op.FiberCoupling(fiber_broken=True)
    assert c.max_power_w() == 0.0
    assert np.all(c.power_w(0.0, np.linspace(0, 80e-6, 9)) == 0.0)


def test_detector_floor_rin_and_saturation():
    det = op.Detector(noise_floor_w=1e-10, rin_db=0.02, averaging_time_s=0.0, seed=3)
    dark = det.measure_array(np.zeros(4000))
    assert np.all(dark >= 0)
    # |N(0, floor)|: RMS equals the floor
    assert math.sqrt(np.mean(dark ** 2)) == pytest.approx(1e-10, rel=0.05)
    lit = det.measure_array(np.full(4000, 1e-3))
    std_db = np.std(10 * np.log10(lit / 1e-3))
    assert std_db == pytest.approx(0.02, rel=0.06)
    sat = op.Detector(saturation_w=2e-3, averaging_time_s=0.0)
    assert sat.measure(5e-3) == pytest.approx(2e-3)


def test_detector_averaging_lag_matches_lag_s():
    det = op.Detector(noise_floor_w=0.0, rin_db=0.0, averaging_time_s=0.5e-3,
                      sample_period_s=1e-3)
    ramp = np.arange(200) * 1e-6             # W per sample
    out = det.measure_array(ramp)
    lag_samples = (ramp[-1] - out[-1]) / 1e-6
    assert lag_samples * 1e-3 == pytest.approx(det.lag_s(), rel=1e-6)
    assert det.lag_s() == pytest.approx(0.1565e-3, rel=0.01)


def test_detector_is_deterministic_for_a_seed():
    a = op.Detector(seed=7).measure_array(np.full(50, 1e-4))
    b = op.Detector(seed=7).measure_array(np.full(50, 1e-4))
    assert np.array_equal(a, b)
