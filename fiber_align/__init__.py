# SPDX-License-Identifier: Apache-2.0
"""
Design, hysteresis modelling and control of a piezoelectric bimorph fiber aligner.

The core (design, hysteresis, control, plant, alignment, analysis) is pure numpy and
never imports rclpy; the ``nodes`` package wraps it for ROS 2.
"""

__version__ = '0.1.0'
