# SPDX-License-Identifier: Apache-2.0
"""The simulated plant: the actuator (amplifier, hysteresis, resonance, sensor)."""
